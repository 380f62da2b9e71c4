#version 460
// layout_probe: touches every member of the structs in glsl/shared/ so that they appear in
// the reflected SPIR-V; the host/GPU layout test compares them with the Rust mirrors.
layout(local_size_x = 1) in;
#include "lib/common.glsl"
#include "shared/types.glsl"
layout(set = 0, binding = 0, scalar) buffer Probe { ProbeStruct probe; };
void main() {
    probe.c = probe.a.x + probe.b.y + float(probe.d);
}
