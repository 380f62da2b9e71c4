#![no_main]
vkinverse_fuzz::target!(Vol);
