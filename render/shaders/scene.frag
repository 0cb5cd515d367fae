#version 330 core
// Shading, LIDAR range and normals in one pass (three float colour attachments).
in vec3 v_rel;
in vec3 v_normal;

uniform vec3 u_camera;          // camera position in world (m), for world-frame tests
uniform vec3 u_axis;            // optical axis (unit, world)
uniform vec3 u_sun;             // unit vector towards the sun (world)
uniform float u_albedo;
uniform int u_brdf;             // 0 Lambert, 1 Lommel-Seeliger, 2 lunar-Lambert (McEwen)
uniform vec3 u_mcewen;          // lunar-Lambert L(g) = 1 + a g + b g^2 + c g^3, g in degrees
uniform float u_log_near;       // log depth: (log(z) - u_log_near) * u_log_scale
uniform float u_log_scale;
uniform int u_use_discard;      // terrain layers: draw only outside the finer layer
uniform vec4 u_discard;         // xmin, ymin, xmax, ymax (world)

uniform int u_shadows;
uniform sampler2DShadow u_shadow_map;
uniform mat4 u_light_from_world;  // world (camera-relative) -> shadow texture [0,1]^3
uniform float u_normal_offset;    // m, along the normal before the lookup
uniform float u_bias;             // depth units, constant
uniform float u_slope_bias;       // depth units per unit tan(incidence)

layout(location = 0) out float out_radiance;
layout(location = 1) out float out_range;
layout(location = 2) out vec4 out_normal;

float reflectance(float mu0, float mu, float g_deg) {
    if (mu0 <= 0.0) return 0.0;
    mu = max(mu, 1e-4);
    if (u_brdf == 0) return u_albedo * mu0;                           // Lambert: A mu0
    float ls = 2.0 * mu0 / (mu0 + mu);                                 // 1 at mu0 = mu = 1
    if (u_brdf == 1) return u_albedo * ls;                             // Lommel-Seeliger
    float L = 1.0 + g_deg * (u_mcewen.x + g_deg * (u_mcewen.y + g_deg * u_mcewen.z));
    return u_albedo * (L * ls + (1.0 - L) * mu0);                      // McEwen (1991)
}

float visibility(vec3 n, float mu0) {
    if (u_shadows == 0 || mu0 <= 0.0) return 1.0;
    vec4 lc = u_light_from_world * vec4(v_rel + n * u_normal_offset, 1.0);
    vec3 c = lc.xyz / lc.w;
    if (c.x < 0.0 || c.x > 1.0 || c.y < 0.0 || c.y > 1.0 || c.z > 1.0) return 1.0;
    float tan_i = sqrt(max(1.0 - mu0 * mu0, 0.0)) / max(mu0, 0.05);
    float ref = c.z - u_bias - u_slope_bias * min(tan_i, 20.0);
    // one bilinear comparison (the map's LINEAR filter gives 2x2 percentage-closer filtering)
    return texture(u_shadow_map, vec3(c.xy, ref));
}

void main() {
    vec3 world = v_rel + u_camera;
    if (u_use_discard == 1 && world.x > u_discard.x && world.x < u_discard.z
            && world.y > u_discard.y && world.y < u_discard.w)
        discard;
    vec3 n = normalize(v_normal);
    float r = length(v_rel);
    vec3 e = -v_rel / r;                       // towards the camera
    float mu0 = dot(n, u_sun);
    float mu = dot(n, e);
    float g = degrees(acos(clamp(dot(u_sun, e), -1.0, 1.0)));
    out_radiance = reflectance(mu0, mu, g) * visibility(n, mu0);
    out_range = r;
    out_normal = vec4(n, 1.0);
    float z = max(dot(v_rel, u_axis), 1e-6);
    gl_FragDepth = clamp((log(z) - u_log_near) * u_log_scale, 0.0, 1.0);
}
