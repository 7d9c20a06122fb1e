"""Fixtures of the diagnosis tests."""

import pytest
from support.independent import case_runner


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    """case -> the diagnosis JSON, made on first use."""
    return case_runner(tmp_path_factory.mktemp("independent"))
