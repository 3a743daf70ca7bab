"""The participant's view: the window and what it draws.

- `window`: the window (`ParticipantView`) and its events; `renderer`: the OpenGL drawing;
- `camera`, `shapes` (the forceps, arrows, rings), `hud`, `font` and `widgets` (text and the
  questionnaire's widgets);
- `normals`: the deforming surface's vertex normals, compiled, every frame;
- `pictures`: offscreen pictures of a run after it ends.

Imports: moderngl, glfw, Pillow, numpy, numba, and `sim` below it (geometry, scenes); nothing imports
it at start-up, a run loads it only for a window or pictures.
"""
