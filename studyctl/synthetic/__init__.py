"""Synthetic participants: people simulated well enough to run a whole study in CI.

- `participant`: the motor and answer models (`SyntheticParticipant`, `SyntheticAnswers`);
  `skill`: a group's skill profile; `observer`: what they perceive, judged against the truth;
  `rig`: the frame times they perceive;
- `synth_run`: registering and running N of them; `bundles`: a session run away from the database
  and stored whole; `plan`: power by simulation; `force_traces`: the truth's line in the force plot.

Imports: `sim`, `analysis` (the truth, the statistics a plan runs), and the study library.
"""
