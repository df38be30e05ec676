from pdr.ahrs.tuning import sliding_grid_search


def test_sliding_grid_search_finds_a_minimum_deterministically():
    def bowl(p):
        return (p["a"] - 0.37) ** 2 + 10 * (p["b"] - 0.021) ** 2

    r1 = sliding_grid_search(bowl, {"a": 1.0, "b": 0.2})
    r2 = sliding_grid_search(bowl, {"a": 1.0, "b": 0.2})
    assert r1.params == r2.params and r1.evaluations == r2.evaluations
    assert abs(r1.params["a"] - 0.37) < 0.02 and abs(r1.params["b"] - 0.021) < 0.005
    assert r1.value < bowl({"a": 1.0, "b": 0.2})


def test_absolute_step_lets_a_parameter_leave_zero():
    r = sliding_grid_search(lambda p: (p["k"] - 0.3) ** 2, {"k": 0.0}, absolute={"k": 0.05})
    assert abs(r.params["k"] - 0.3) < 0.03


def test_grid_points_cover_every_combination():
    from pdr.ahrs.tuning import grid_points

    pts = grid_points({"a": [1, 2], "b": [10, 20, 30]})
    assert len(pts) == 6 and pts[0] == {"a": 1.0, "b": 10.0} and pts[-1] == {"a": 2.0, "b": 30.0}


def test_leave_one_out_scores_each_recording_with_a_choice_made_without_it():
    import numpy as np

    from pdr.ahrs.tuning import leave_one_out

    # point 0 is best on recordings 0-2 but terrible on 3; point 1 is decent everywhere
    table = np.array([[1.0, 1.0, 1.0, 9.0],
                      [2.0, 2.0, 2.0, 2.0]])
    cv = leave_one_out(table)
    assert cv.chosen == 1  # mean 3.0 against 2.0
    # holding out 3, point 0 looks best (mean 1.0 on the others) and scores 9 there
    assert cv.folds[3] == (3, 0, 9.0)
    # holding out 0, point 1 wins (means 3.67 against 2.0)
    assert cv.folds[0] == (0, 1, 2.0)
    assert cv.held_out_mean == (2.0 + 2.0 + 2.0 + 9.0) / 4


def test_leave_one_out_needs_two_recordings():
    import pytest

    from pdr.ahrs.tuning import leave_one_out

    with pytest.raises(ValueError, match=">= 2 recordings"):
        leave_one_out([[1.0], [2.0]])


def test_balanced_criterion_gives_every_group_one_vote():
    import numpy as np
    import pytest

    from pdr.ahrs.tuning import criterion, leave_one_out

    # three recordings of data set A, one of B: point 0 suits A a little better, point 1 suits B much better
    table = np.array([[1.0, 1.0, 1.0, 4.0],
                      [2.1, 2.1, 2.1, 1.0]])
    groups = ["A", "A", "A", "B"]
    assert np.allclose(criterion(table, range(4)), [1.75, 1.825])  # per recording A outvotes B 3:1
    assert np.allclose(criterion(table, range(4), groups), [2.5, 1.55])  # one vote per data set
    assert leave_one_out(table).chosen == 0
    cv = leave_one_out(table, groups)
    assert cv.chosen == 1
    # holding out B's only recording leaves A alone to choose: point 0, which scores 4 on B
    assert cv.folds[3] == (3, 0, 4.0)
    # holding out one of A's, both data sets still vote: point 1
    assert cv.folds[0] == (0, 1, 2.1)
    with pytest.raises(ValueError, match="3 group labels for 4 recordings"):
        leave_one_out(table, groups[:3])
