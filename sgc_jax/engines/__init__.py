"""The two engines of docs/semantics.md §7 (``jax_engine``: jitted kernels; ``reference``: NumPy +
OpenCV), the scale-free units both share, and JAX's persistent compilation cache. An engine turns
clips into per-pair arrays (``sgc_jax.io.result.PairArrays``); scoring them is ``sgc_jax.api``'s job.
"""
