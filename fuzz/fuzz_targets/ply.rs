#![no_main]
vkinverse_fuzz::target!(Ply);
