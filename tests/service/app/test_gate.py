from service.app.gate import CommandGate
from service.edges.telemetry import Heartbeat


def hb(t: float, mode: int = 15, armed: bool = True, system: int = 1) -> Heartbeat:
    return Heartbeat(
        t, system=system, component=1, vehicle_type=10, autopilot=3, custom_mode=mode, armed=armed
    )


def test_only_armed_guided_and_alive() -> None:
    gate = CommandGate(guided_mode=15, link_timeout_s=3.0)
    assert not gate.state(0.0).allowed
    assert "no autopilot" in gate.state(0.0).reason
    gate.heard(hb(1.0, armed=False))
    assert gate.state(1.5).reason == "vehicle disarmed"
    gate.heard(hb(2.0, mode=4))
    assert not gate.state(2.5).allowed
    assert "not in GUIDED (mode 4" in gate.state(2.5).reason
    gate.heard(hb(3.0))
    assert gate.state(3.5).allowed
    assert gate.state(6.0).allowed
    lost = gate.state(6.01)
    assert not lost.allowed
    assert lost.reason.startswith("link lost")
    gate.heard(hb(7.0))
    assert gate.state(7.0).allowed  # recovery needs no restart


def test_other_systems_do_not_steer_the_gate() -> None:
    gate = CommandGate(guided_mode=15, link_timeout_s=3.0)
    gate.heard(hb(1.0, system=1))
    gate.heard(hb(2.0, system=2, mode=4))
    assert gate.system == 1
    assert gate.state(2.0).allowed
