//! PLY.
