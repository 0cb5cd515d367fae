#version 330 core
// The surface pass: what the shading pass (shade.frag) needs of each pixel's nearest fragment,
// with the normals: its camera-relative position and extra shadow bias,
// and a body's per-vertex albedo factor and scattered light where its batch carries them
// (the maps, the albedo's and the scattered light's, the shading pass looks up itself).
//
// Specialised at compile time: the renderer prepends a #define for each switch below (the
// maps and per-vertex values a batch carries), so a program holds only the paths its
// batches take (a CPU rasteriser pays for every instruction of an untaken branch). Without
// them (the generic program), each switch is read from its uniform.
#ifndef SPECIALISED
uniform int u_vertex_albedo;    // 1: v_albedo scales the albedo
uniform int u_use_discard;      // terrain layers: draw only outside the finer layer
uniform int u_normal_map;       // terrain layers: shade with the layer's full-resolution
uniform int u_normal_cube;      // asteroid bodies: shade with the finest level's normals
uniform int u_vertex_scatter;   // 1: v_scatter is the scattered light (bodies), not the map
#define VERTEX_ALBEDO u_vertex_albedo
#define DISCARD u_use_discard
#define NORMAL_MAP u_normal_map
#define NORMAL_CUBE u_normal_cube
#define VERTEX_SCATTER u_vertex_scatter
#endif
in vec3 v_rel;
in vec3 v_normal;
in float v_albedo;              // per-vertex albedo factor, used where VERTEX_ALBEDO is 1
in float v_shadow_bias;          // geomorphing terrain: extra bias of coarse geometry
in float v_scatter;              // bodies: per-vertex scattered irradiance / solar, used where
                                 // VERTEX_SCATTER is 1 (render.body_scattering)

uniform vec3 u_camera;          // camera position in world (m), for world-frame tests
uniform vec4 u_discard;         // xmin, ymin, xmax, ymax (world)

uniform samplerCube u_normal_cube_map;  // looked up by body-frame direction from the centre
uniform mat3 u_world_from_model;  // (the body rotation, as in the vertex stage)
uniform vec3 u_model_offset;      // the body's centre relative to the camera (vertex stage)
uniform sampler2D u_normals;    // normals (texture of unit normals, one texel per pixel),
uniform vec4 u_normal_rect;     // whatever the level of detail: (x0, y0, 1/width, 1/height)

layout(location = 0) out vec4 out_normal;
layout(location = 1) out vec4 out_rel;       // v_rel, v_shadow_bias
layout(location = 2) out vec2 out_vertex;    // v_albedo, v_scatter (bodies that carry them)

void main() {
    vec3 world = v_rel + u_camera;
    if (DISCARD == 1 && world.x > u_discard.x && world.x < u_discard.z
            && world.y > u_discard.y && world.y < u_discard.w)
        discard;
    vec3 n = normalize(v_normal);
    if (NORMAL_MAP == 1)
        n = normalize(texture(u_normals, vec2((world.x - u_normal_rect.x) * u_normal_rect.z,
                                               (u_normal_rect.y - world.y) * u_normal_rect.w)).xyz);
    if (NORMAL_CUBE == 1)
        n = normalize(u_world_from_model
                      * texture(u_normal_cube_map,
                                transpose(u_world_from_model) * (v_rel - u_model_offset)).xyz);
    out_normal = vec4(n, 1.0);
    out_rel = vec4(v_rel, v_shadow_bias);
    if (VERTEX_ALBEDO == 1 || VERTEX_SCATTER == 1)
        out_vertex = vec2(VERTEX_ALBEDO == 1 ? v_albedo : 1.0,
                          VERTEX_SCATTER == 1 ? v_scatter : 0.0);
}
