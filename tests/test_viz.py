"""Pictures (`geofeat.viz`): edge inputs give a picture or a clear error."""

import numpy as np
import pytest

import geofeat
from geofeat.geodesic.polar import PolarPatches
from geofeat.viz import draw_geodesic_support, draw_matches, patch_grid


def _no_patches() -> PolarPatches:
    return PolarPatches(np.zeros((0, 2)), np.zeros((0, 32, 32), np.float32), np.zeros((0, 32, 32, 2), np.float32),
                        np.zeros(0, bool), np.zeros((0, 32), np.int32), np.zeros((0, 32, 32, 3), np.float32), 0.075)


def test_pictures_of_no_keypoints_are_the_bare_frame():
    frame = geofeat.read_demo_frame()
    empty = _no_patches()
    assert (draw_geodesic_support(frame, empty) == frame.color).all()
    assert (patch_grid(empty) == 255).all()
    both = draw_matches(frame, frame, np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, np.int64))
    assert both.shape == (frame.shape[0], 2 * frame.shape[1], 3)


@pytest.mark.parametrize("kwargs", [dict(columns=0), dict(zoom=0), dict(columns=-1), dict(columns=2.5)])
def test_patch_grid_refuses_meaningless_layouts(kwargs):
    # columns=0: ZeroDivisionError; zoom=0: an OpenCV assertion in resize; columns=-1: "negative dimensions"
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        patch_grid(_no_patches(), **kwargs)
