"""JAX kernels: pure functions of arrays with static shapes and validity masks, one pair or frame at a
time (``vmap`` lifts them). They import only each other, ``sgc_jax.config``, ``sgc_jax.codes`` and
``sgc_jax.stats`` (the means written once for NumPy and ``jax.numpy``).
"""
