"""Shared fixtures: the shipped and printed models, and a sine fitter."""

import tempfile
from pathlib import Path

import pytest

from cryod.cli import use_one_blas_thread
from cryod.model import load_model

use_one_blas_thread()          # as the command line does for the daemon and the model tools

REPOSITORY = Path(__file__).resolve().parent.parent
CONFIG = REPOSITORY / "config"
DATA = Path(__file__).resolve().parent / "data"
CALIBRATION_DATA = DATA / "calibration"


@pytest.fixture(scope="session")
def reference_model():
    """config/model.yaml, the shipped model."""
    return load_model(CONFIG / "model.yaml")


@pytest.fixture(scope="session")
def printed_model():
    """The paper's equations exactly as printed."""
    return load_model(CONFIG / "model-paper-printed.yaml")


@pytest.fixture
def runtime_dir():
    """A private per-user runtime folder (for ``XDG_RUNTIME_DIR``) on a short path: a dry run's control
    socket goes in it, and a Unix socket's path holds at most 107 bytes however deep pytest's folders are."""
    with tempfile.TemporaryDirectory(prefix="cryod-run-") as folder:        # mode 0700
        yield Path(folder)


@pytest.fixture(scope="session")
def quiet_reference_model(reference_model):
    """Shipped model without the PTC oscillation (for step responses)."""
    return reference_model.with_ptc(ptc_stage_amplitude_K=0.0)
