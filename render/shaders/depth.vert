#version 330 core
// Shadow-map pass: the same vertices seen from the sun (orthographic).
uniform mat4 u_clip_from_world;
uniform mat3 u_world_from_model;
uniform vec3 u_model_offset;
in vec3 in_position;
out vec2 v_xy;
void main() {
    vec3 w = u_world_from_model * in_position + u_model_offset;
    v_xy = w.xy;
    gl_Position = u_clip_from_world * vec4(w, 1.0);
}
