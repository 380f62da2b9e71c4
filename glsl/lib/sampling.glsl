// Sampling helpers shared by the integrator passes (pbrt-v4 naming).
#ifndef SAMPLING_GLSL
#define SAMPLING_GLSL

// Uniform point on a triangle from two uniform numbers, as barycentrics (b1, b2)
// (Turk 1990: the square-root map).
vec2 sample_triangle_barycentrics(vec2 u) {
    float s = sqrt(u.x);
    return vec2(1.0 - s, u.y * s);
}

// Power heuristic with beta = 2 (Veach 1997).
float power_heuristic(float pdf_a, float pdf_b) {
    float a = pdf_a * pdf_a;
    float b = pdf_b * pdf_b;
    return a + b > 0.0 ? a / (a + b) : 0.0;
}

float luminance(vec3 c) { return dot(c, vec3(0.2126, 0.7152, 0.0722)); }

float max_component(vec3 v) { return max(v.x, max(v.y, v.z)); }
#endif
