"""The servo: the 1 kHz haptic loop and how it runs.

- `loop`: one tick (`ServoLoop`): read the devices, evaluate each contact's law, apply the safety
  rules (force and rate limits; a NaN, a fault or an unstable step gives zero force and an event);
- `lockstep`: quiet ticks compiled, run between visual frames when nothing real-time is attached;
- `process`: the servo in its own process in real time, and `child` that process's own side;
- `messages`: the typed messages on the pipe between the two processes.

Imports: numpy, numba, and `sim` below it (devices, laws, models' base types); never the view.
"""
