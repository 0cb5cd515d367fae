#version 330 core
// Scene vertices: model coordinates -> world (rotation + offset) -> clip.
// Positions stay camera-relative on the GPU so that float32 keeps millimetres at 100 km.
uniform mat4 u_clip_from_camera_rel;   // projection * view rotation (no translation)
uniform mat3 u_world_from_model;       // body rotation (asteroids); identity for terrain
uniform vec3 u_model_offset;           // model origin in world, relative to the camera
in vec3 in_position;
in vec3 in_normal;
in float in_albedo;                    // per-vertex albedo factor (bodies); see u_vertex_albedo
uniform int u_vertex_albedo;           // 1: in_albedo is bound; 0: factor 1
out vec3 v_rel;      // world position minus camera position (m)
out vec3 v_normal;   // world-frame normal (not normalised)
out float v_albedo;  // albedo factor (1 unless the mesh carries one per vertex)
void main() {
    v_rel = u_world_from_model * in_position + u_model_offset;
    v_normal = u_world_from_model * in_normal;
    v_albedo = u_vertex_albedo == 1 ? in_albedo : 1.0;
    gl_Position = u_clip_from_camera_rel * vec4(v_rel, 1.0);
}
