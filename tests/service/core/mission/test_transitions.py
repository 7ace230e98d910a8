"""The transitions table: which cue moves the mission from which state to which."""

from service.core.mission.events import MissionState
from service.core.mission.transitions import TRANSITIONS, Cue

FIND, TRACE, LOST, DECLARED = MissionState.FIND, MissionState.TRACE, MissionState.LOST, MissionState.DECLARED


def test_odour_traces_from_the_sweep_or_the_cast_and_changes_nothing_while_tracing() -> None:
    assert TRANSITIONS[FIND, Cue.ODOUR] is TRACE
    assert TRANSITIONS[LOST, Cue.ODOUR] is TRACE
    assert (TRACE, Cue.ODOUR) not in TRANSITIONS


def test_only_tracing_is_lost_and_a_lone_contact_goes_back_to_the_sweep() -> None:
    assert {(s, c) for (s, c) in TRANSITIONS if c in (Cue.QUIET, Cue.LONE_QUIET)} == {
        (TRACE, Cue.QUIET),
        (TRACE, Cue.LONE_QUIET),
    }
    assert TRANSITIONS[TRACE, Cue.QUIET] is LOST
    assert TRANSITIONS[TRACE, Cue.LONE_QUIET] is FIND


def test_the_source_may_be_declared_from_every_state_but_declared_is_final() -> None:
    assert all(TRANSITIONS[s, Cue.SOURCE] is DECLARED for s in (FIND, TRACE, LOST))
    # a check is flown while tracing, wherever its rule fired
    assert {s: TRANSITIONS[s, Cue.CHECK] for s in (FIND, LOST)} == {FIND: TRACE, LOST: TRACE}
    assert (TRACE, Cue.CHECK) not in TRANSITIONS
    assert not any(s is DECLARED for s, _ in TRANSITIONS)
