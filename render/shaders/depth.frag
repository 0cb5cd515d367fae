#version 330 core
in vec2 v_xy;
uniform int u_use_discard;
uniform vec4 u_discard;
void main() {
    if (u_use_discard == 1 && v_xy.x > u_discard.x && v_xy.x < u_discard.z
            && v_xy.y > u_discard.y && v_xy.y < u_discard.w)
        discard;
}
