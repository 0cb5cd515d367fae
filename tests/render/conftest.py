"""GL test fixtures: one context per session, checked and reset around each test.

As in moderngl's own ``tests/conftest.py``: the session's context is made current before every
test that uses it, ``ctx.error`` must read ``GL_NO_ERROR`` before the test (nothing earlier left
an error behind) and after it (the test's own GL calls raised none), and the pipeline state a
test may change (capabilities, depth and blend functions, scissor, culling) is put back to
OpenGL's defaults, so no test depends on the order the tests run in (the renderer sets its
viewport on every pass).
"""

import pytest

#: The error flag of a context with nothing to report (moderngl's ``Context.error``).
NO_ERROR = "GL_NO_ERROR"


@pytest.fixture(scope="session")
def gl():
    from render.context import create_context
    from render.errors import RenderUnavailableError

    try:
        return create_context()
    except RenderUnavailableError as exc:
        pytest.skip(f"no headless OpenGL here: {exc}")


def _reset(ctx):
    """Put back the state OpenGL starts with (what a fresh context would have)."""
    import moderngl

    ctx.enable_only(moderngl.NOTHING)
    ctx.depth_func = "<"
    ctx.blend_func = moderngl.DEFAULT_BLENDING
    ctx.blend_equation = moderngl.FUNC_ADD
    ctx.front_face = "ccw"
    ctx.cull_face = "back"
    ctx.wireframe = False
    ctx.polygon_offset = (0.0, 0.0)
    ctx.scissor = None


@pytest.fixture(autouse=True)
def _gl_checked_and_reset(request):
    """Around every test that uses ``gl`` (directly or through ``renderer``)."""
    if "gl" not in request.fixturenames:
        yield
        return
    ctx = request.getfixturevalue("gl")
    before = ctx.error
    if before != NO_ERROR:
        pytest.fail(f"an earlier test left {before} on the session's GL context")
    yield
    after = ctx.error
    _reset(ctx)
    assert after == NO_ERROR, f"this test left {after} on the GL context"
    assert ctx.error == NO_ERROR, "resetting the GL state raised an error"


@pytest.fixture
def renderer(gl):
    from render.renderer import Renderer

    r = Renderer(gl)
    yield r
    assert gl.error == NO_ERROR
