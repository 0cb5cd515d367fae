"""GL test fixtures: one context per session, an error check around each test."""

import pytest


@pytest.fixture(scope="session")
def gl():
    from render.context import create_context
    from render.errors import RenderUnavailableError

    try:
        return create_context()
    except RenderUnavailableError as exc:
        pytest.skip(f"no headless OpenGL here: {exc}")


@pytest.fixture
def renderer(gl):
    from render.renderer import Renderer

    r = Renderer(gl)
    yield r
    assert gl.error == "GL_NO_ERROR"
