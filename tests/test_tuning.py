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
