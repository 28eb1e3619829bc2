"""The two engines of docs/semantics.md §7, each turning a clip into per-pair arrays (``pairs``):
the JAX engine (``jax_engine/``: stages, compiled programs, dispatch) and the NumPy + OpenCV
reference (``reference/``, one module per step of §3), with the scale-free units both share (``units``).
"""
