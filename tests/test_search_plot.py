"""starts.png (``search.plot``): every outcome is drawn where its start offset is, in its colour."""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd

from deepcrashtest.scenario import SplineParams
from deepcrashtest.search.plot import GREEN, RED, plot_starts
from deepcrashtest.search.space import SearchSpace


def test_outcomes_are_drawn_at_their_offsets(tmp_path):
    spline = SplineParams(knots=[0, 0, 0, 0, 1, 1, 1, 1], cx=[0, 1, 2, 3], cy=[0, 0, 0, 0], degree=3)
    space = SearchSpace(spline=spline, yaw0=0.0, t=(0.0, 1.0))
    df = pd.DataFrame(
        {
            "variant": [0, 1, 2, 3],
            "method": ["random", "random", "cem", "cem"],
            "safe": [True, False, True, False],
            "d_lat": [1.5, -1.5, 1.5, -1.5],  # left +
            "d_lon": [3.0, 3.0, -3.0, -3.0],  # forward +
        }
    )
    boundary = {"angle_deg": [0.0, 90.0, 180.0, 270.0], "radius_m": [2.0, None, 2.0, 1.0]}
    out = plot_starts(df, space.half_box, boundary, None, tmp_path / "starts.png", False, "four variants")
    img = cv2.imread(str(out))
    assert img is not None and img.shape[2] == 3

    def colour_near(colour, left: bool, top: bool) -> bool:
        h, w = img.shape[:2]
        ys = slice(0, h // 2) if top else slice(h // 2, h * 4 // 5)  # the legend is below the axes
        xs = slice(0, w // 2) if left else slice(w // 2, w)
        return bool((np.abs(img[ys, xs].astype(int) - colour).sum(axis=2) < 30).any())

    # safe left-forward (top left) and unsafe right-forward (top right); CEM: safe bottom left, unsafe bottom right
    assert colour_near(GREEN, True, True) and colour_near(RED, False, True)
    assert colour_near(GREEN, True, False) and colour_near(RED, False, False)
    assert not colour_near(RED, True, True) and not colour_near(GREEN, False, False)
