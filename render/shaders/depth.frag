#version 330 core
// Shadow-map pass: depth only. Built twice (render/renderer.py): with DISCARD_RECT for the
// batches whose fragments inside a finer terrain layer's extent are discarded, and without
// it for every other batch: a shader that may discard costs llvmpipe every fragment, even
// where the test fails, and an empty one lets it write depth straight from the rasteriser.
#ifdef DISCARD_RECT
in vec2 v_xy;
uniform vec4 u_discard;
#endif
void main() {
#ifdef DISCARD_RECT
    if (v_xy.x > u_discard.x && v_xy.x < u_discard.z
            && v_xy.y > u_discard.y && v_xy.y < u_discard.w)
        discard;
#endif
}
