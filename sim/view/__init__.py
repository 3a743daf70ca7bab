"""The participant's view: the window and what it draws.

- `window`: the window (`ParticipantView`) and its events; `renderer`: the OpenGL drawing;
- `camera`, `shapes` (the forceps, arrows, rings), `hud`, `font` and `widgets` (text and the
  questionnaire's widgets);
- `normals`: the deforming surface's vertex normals, compiled, every frame;
- `pictures`: offscreen pictures of a run after it ends;
- `hands`: what the view draws of each hand, which a run builds without loading the window.

Imports: moderngl, glfw, Pillow, numpy, numba, and `sim` below it (geometry, scenes); nothing imports
it at start-up but `hands` and `camera`, a run loads the rest only for a window or pictures.
"""
