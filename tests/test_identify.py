"""Profile-likelihood intervals: their ends read from the grid, and what to distrust."""


def test_profile_interval_interpolates_its_ends_and_says_when_the_grid_is_too_coarse():
    from rotorbayes.inference.identify import profile_interval

    grid = [float(v) for v in range(11)]
    iv = profile_interval({"grid": grid, "delta_chi2": [(g - 5.0) ** 2 for g in grid]})
    assert abs(iv["lo"] - (5 - 1.96)) < 0.05 and abs(iv["hi"] - (5 + 1.96)) < 0.05
    assert iv["inside"] == 3 and iv["note"] == ""
    # Three points, only the estimate inside: the interval is not zero wide, and it says so.
    iv = profile_interval({"grid": [3.0, 5.0, 7.0], "delta_chi2": [16.0, 0.0, 16.0]})
    assert 3.0 < iv["lo"] < 5.0 < iv["hi"] < 7.0
    assert "only 1 grid point(s) inside" in iv["note"]
    # Inside up to the grid's edge: the interval may be wider.
    iv = profile_interval({"grid": [4.0, 5.0, 6.0], "delta_chi2": [1.0, 0.0, 1.0]})
    assert (iv["lo"], iv["hi"]) == (4.0, 6.0) and "grid's edge" in iv["note"]
    assert profile_interval({"grid": [1.0, 2.0], "delta_chi2": [9.0, None]})["lo"] is None
