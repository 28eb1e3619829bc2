"""JAX kernels: pure functions of arrays with static shapes and validity masks, one pair or frame at a
time (``vmap`` lifts them). They import only each other, ``sgc_jax.config`` and ``sgc_jax.codes``.
"""
