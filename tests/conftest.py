"""Shared fixtures: the element FMUs, built once per test session."""
import pytest


@pytest.fixture(scope="session")
def fmus():
    """{model name: path of its .fmu}, built (or reused if up to date) by ``fmus.build.build_all``."""
    from fmus.build import build_all
    return build_all(log=lambda *a: None)
