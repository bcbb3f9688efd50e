"""Rendering in tests: a machine without headless OpenGL skips, naming why."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import pytest


def no_gl(e: Exception) -> bool:
    """Whether ``e`` says the machine has no headless OpenGL (EGL)."""
    return "EGL" in repr(e) or "OpenGL" in repr(e) or "gl" in type(e).__name__.lower()


@contextlib.contextmanager
def gl_or_skip(env=None) -> Iterator[None]:
    """Render inside: a missing OpenGL skips the test; ``env`` is closed at the end."""
    try:
        yield
    except Exception as e:
        if no_gl(e):
            pytest.skip(f"no headless OpenGL: {e!r}")
        raise
    finally:
        if env is not None:
            env.close()
