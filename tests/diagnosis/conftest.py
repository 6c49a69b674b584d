"""What several diagnosis tests share (beside tests/conftest.py's machine, simulated run and plate run)."""

import pytest


@pytest.fixture(scope="module")
def plate():
    """The KOBA 0420 ball plate (``artefacts.load_artefact("koba-0420")``), the artefact the plate diagnoses hide
    their effects on."""
    from cmmpose import artefacts

    return artefacts.load_artefact("koba-0420")
