"""A session: a participant's run through a protocol's conditions.

- `run`: training, conditions, trials, questions, resume (`run_session`); `lock`: one process
  per session; `traces`: every stored trace read back through the store;
- `discrimination`, `procedures`: the two-interval task and its adaptive procedure;
- `asking`, `window_answers`: asking in the terminal and in the window;
- `trial_replay`: a stored trial played back.

Imports: `sim` (scenes, runs; the view and the real-time servo only for a window or a real-time
run), `analysis` (questions, trace files, errors), the store and the study library.
"""
