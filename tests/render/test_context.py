"""Which EGL device renders: a GPU when there is one, the CPU otherwise, never an error."""

from __future__ import annotations

import pytest

from render.context import DEVICE_ENV, SOFTWARE_EXTENSION, EglDevice, choose_device
from render.errors import RenderUnavailableError

NVIDIA = EglDevice(0, ("EGL_NV_device_cuda", "EGL_EXT_device_drm"), "NVIDIA H200",
                   "/dev/dri/card1")
LLVMPIPE = EglDevice(1, (SOFTWARE_EXTENSION, "EGL_EXT_device_drm_render_node"))
AMD = EglDevice(2, ("EGL_EXT_device_drm",), "AMD Radeon", "/dev/dri/card2")


@pytest.mark.parametrize(("devices", "request_", "index"), [
    ([NVIDIA, LLVMPIPE], None, 0),           # a GPU when there is one
    ([LLVMPIPE, NVIDIA], "auto", 0),         # whatever the order EGL lists them in
    ([LLVMPIPE, AMD], "", 2),                # any hardware, not NVIDIA's only
    ([LLVMPIPE], None, 1),                   # the CPU otherwise
    ([NVIDIA, LLVMPIPE], "software", 1),     # the CPU on request (bit-identical goldens)
    ([NVIDIA, LLVMPIPE, AMD], " 2 ", 2),     # a device by index
])
def test_the_device_chosen(devices, request_, index):
    assert choose_device(devices, request_).index == index


def test_no_enumeration_means_the_default_display():
    assert choose_device([], None) is None


@pytest.mark.parametrize(("devices", "request_", "words"), [
    ([NVIDIA], "software", "no software device"),
    ([NVIDIA, LLVMPIPE], "5", "lists 2 device"),
    ([NVIDIA], "gpu", "auto, software or a device index"),
])
def test_a_device_that_is_not_there_is_one_line_naming_the_variable(devices, request_, words):
    with pytest.raises(RenderUnavailableError, match=words) as info:
        choose_device(devices, request_)
    assert DEVICE_ENV in str(info.value) and "\n" not in str(info.value)


def test_the_context_says_which_device_it_renders_on(gl):
    from render.context import describe, egl_devices

    devices = egl_devices()
    facts = describe()
    assert facts["egl_devices"] == len(devices)
    if not devices:
        pytest.skip("EGL lists no devices here: the default display renders")
    chosen = next(d for d in devices if d.index == facts["egl_device"])
    assert facts["hardware"] == (not chosen.software)
    if chosen.software:
        assert "llvmpipe" in facts["renderer"] or "softpipe" in facts["renderer"]
    # the automatic choice is never the CPU while a GPU is listed
    assert chosen.software == all(d.software for d in devices)


@pytest.mark.parametrize(("devices", "chosen", "tried"), [
    ([NVIDIA, LLVMPIPE], NVIDIA, [0, 1, None]),   # a failing GPU: the CPU, then EGL's default
    ([NVIDIA, LLVMPIPE], LLVMPIPE, [1, None]),
    ([NVIDIA], NVIDIA, [0, None]),                # no software device listed
    ([], None, [None]),                           # no enumeration: EGL's default only
])
def test_a_device_that_fails_falls_back_to_the_cpu_then_the_default(devices, chosen, tried):
    from render.context import fallbacks

    assert [d.index if d is not None else None for d in fallbacks(devices, chosen)] == tried
