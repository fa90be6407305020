"""`fabric_texture` was one 81-line if/elif; it is now table-driven (`_PATTERNS`). The if/elif
version is read from git history (the blob of src/geofeat/sim/textures.py before the change, so it
survives rebases) and must give the same bytes for every kind and a few seeds; the test is skipped
where that history is not available (a source archive, a shallow clone)."""

import subprocess
from pathlib import Path

import numpy as np
import pytest

from geofeat.sim import textures
from geofeat.sim.textures import FABRIC_KINDS, fabric_texture

IF_ELIF_BLOB = "340094fd40a5c6fad80950dbaae9286e0868f78b"
REPO = Path(__file__).resolve().parents[1]


def _if_elif_version():
    try:
        source = subprocess.run(["git", "show", IF_ELIF_BLOB], cwd=REPO,
                                capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("git history with the if/elif version is not available")
    namespace = {"__name__": "fabric_texture_if_elif"}
    exec(compile(source, "textures@" + IF_ELIF_BLOB[:8], "exec"), namespace)
    return namespace["fabric_texture"]


@pytest.mark.parametrize("kind", list(FABRIC_KINDS) + [None])
def test_fabric_texture_same_bytes_as_the_if_elif_version(kind):
    reference = _if_elif_version()
    for seed in (0, 1, 7):
        new = fabric_texture(np.random.default_rng(seed), kind, width=160, height=120)
        ref = reference(np.random.default_rng(seed), kind, width=160, height=120)
        assert new.dtype == ref.dtype == np.uint8 and new.shape == ref.shape == (120, 160, 3)
        assert new.tobytes() == ref.tobytes(), (kind, seed)


def test_every_kind_has_a_pattern_and_the_same_seed_gives_the_same_bytes():
    assert set(textures._PATTERNS) == set(FABRIC_KINDS)
    a = fabric_texture(np.random.default_rng(3), "plaid", width=64, height=48)
    assert a.tobytes() == fabric_texture(np.random.default_rng(3), "plaid", width=64, height=48).tobytes()


def test_fabric_texture_unknown_kind():
    with pytest.raises(ValueError, match="kind"):
        fabric_texture(np.random.default_rng(0), "tartan")
