from service.core.grid import Grid
from service.core.mission.prospect import DEFAULT_STEP_M, Prospect


def grid() -> Grid:
    return Grid(0.0, 100.0, 0.0, 100.0, columns=10, rows=10)


def test_step_is_the_median_move_per_tick() -> None:
    prospect = Prospect(grid())
    assert prospect.step_m == DEFAULT_STEP_M
    for x in (0.0, 1.5, 3.0, 4.5):
        prospect.observe(x, 0.0)
    assert prospect.step_m == 1.5


def test_a_move_made_in_another_state_is_not_a_tick() -> None:
    """After a trace the mission comes back to FIND far from where it left it: that jump is not
    one tick's move, so it must not raise the step the next leg is sampled at."""
    prospect = Prospect(grid())
    for x in (0.0, 1.0, 2.0):
        prospect.observe(x, 0.0)
    prospect.restart()
    prospect.observe(60.0, 0.0)
    prospect.observe(61.5, 0.0)
    assert prospect.step_m == 1.0
