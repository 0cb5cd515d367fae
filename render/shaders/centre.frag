#version 330 core
// An antialiased frame's range and normals at each pixel's centre sample: sample
// u_factor x + (u_factor - 1) / 2 of pixel x in columns and rows (u_factor odd), copied exactly.
uniform int u_factor;
uniform sampler2D u_range;
uniform sampler2D u_normal;
layout(location = 1) out float out_range;
layout(location = 2) out vec4 out_normal;
void main() {
    ivec2 p = ivec2(gl_FragCoord.xy) * u_factor + (u_factor - 1) / 2;
    out_range = texelFetch(u_range, p, 0).r;
    out_normal = texelFetch(u_normal, p, 0);
}
