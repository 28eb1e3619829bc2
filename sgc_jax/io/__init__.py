"""Clip and result I/O: the clip schema and its files (``clip``, ``loading``, ``npz``), content checks
(``validate``) and the per-pair, per-clip and batch result tables (``result``). Imports only
``sgc_jax.config``, ``sgc_jax.codes``, the score formula (``sgc_jax.calibration``), ``sgc_jax.stats``
and each other.
"""
