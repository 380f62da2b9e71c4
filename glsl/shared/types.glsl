// Structs shared by host and kernels. Each is mirrored by a #[repr(C)] struct in
// src/shared.rs, and a test compares the reflected member offsets with the Rust ones
// (scalar block layout: members are packed at their scalar alignment).
#ifndef TYPES_GLSL
#define TYPES_GLSL
// 32 bytes: a vec3, a vec3, a float and a uint.
struct ProbeStruct {
    vec3 a;
    vec3 b;
    float c;
    uint d;
};
#endif
