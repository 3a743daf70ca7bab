"""Faults at the servo: every case sends zero or a force within limits, and logs an event."""

import math

import numpy as np
import pytest

from sim.devices.base import DeviceState
from sim.models.api import Contact, TissueModel
from sim.servo.loop import Hand, ServoLoop


class Scripted:
    """A device that plays positions and then misbehaves at tick `at` in the way asked."""

    def __init__(self, fault: str, at: int = 50):
        self.fault, self.at, self.k = fault, at, 0
        self.sent: list[tuple] = []

    def read(self, t):
        self.k += 1
        p = (0.001 * min(self.k, 40) / 40, 0.0, 0.0)  # moves 1 mm away from the grasp point
        if self.k >= self.at:
            if self.fault == "nan":
                p = (math.nan, 0.0, 0.0)
            elif self.fault == "jump":
                p = (p[0] + 0.05, p[1], p[2])
            elif self.fault == "disconnect":
                raise OSError("device unplugged")
            elif self.fault == "fault":
                return DeviceState(position=p, button=True, fault="HD_DEVICE_FAULT")
        return DeviceState(position=p, button=True)

    def write_force(self, f):
        self.sent.append(tuple(f))

    def close(self):
        pass


class Spring(TissueModel):
    def __init__(self, k):
        self.k = k

    def force(self, contact, d):
        return (-self.k * d[0], -self.k * d[1], -self.k * d[2])


def _run(fault, k=500.0, ticks=120):
    dev = Scripted(fault)
    hand = Hand(index=0, name="h", device=dev)
    servo = ServoLoop(model=Spring(k), hands=[hand], peak_force=3.3, ramp_s=0.01)
    servo.tick(0.0)
    hand.contact_t = 0.0
    hand.contact = Contact(hand=0, vertex=0, point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0))
    for i in range(1, ticks):
        servo.tick(i / 1000)
    return dev, servo, hand


@pytest.mark.parametrize("fault, event", [("nan", "nan_position"), ("jump", "position_jump"), ("disconnect", "device_fault"), ("fault", "device_fault")])
def test_device_faults_give_zero_force_and_an_event(fault, event):
    dev, servo, hand = _run(fault)
    sent = np.array(dev.sent)
    assert np.all(np.isfinite(sent))
    assert np.linalg.norm(sent, axis=1).max() <= 3.3
    assert np.linalg.norm(sent[:45], axis=1).max() > 0.1  # the spring was felt before the fault
    after = sent[50:] if fault != "disconnect" else sent[49:]
    assert np.all(after == 0.0)
    kinds = [e.kind for e in servo.events]
    assert kinds.count(event) == 1  # logged once, when it starts
    assert hand.contact is None  # the grasp is dropped: a new grasp is needed
    ev = next(e for e in servo.events if e.kind == event)
    assert ev.t == pytest.approx(0.049, abs=0.002)


def test_force_above_the_peak_is_clamped_not_sent():
    dev, servo, _ = _run("none", k=1e5, ticks=60)
    sent = np.linalg.norm(np.array(dev.sent), axis=1)
    assert sent.max() == pytest.approx(3.3)
    assert np.all(sent <= 3.3 + 1e-12)
    assert [e.kind for e in servo.events].count("force_clamped") == 1


def test_deadline_streak_suspends_force_output():
    dev, servo, hand = _run("none", ticks=40)
    servo.suspend(0.04, 0.1, "deadline_streak")
    for i in range(40, 200):
        servo.tick(i / 1000)
    sent = np.linalg.norm(np.array(dev.sent), axis=1)
    assert np.all(sent[40:140] == 0.0)  # back after 100 ms
    assert sent[150:].max() > 0.1
    assert [e.kind for e in servo.events].count("deadline_streak") == 1
