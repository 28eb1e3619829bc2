"""The JAX engine (docs/semantics.md §7.1): a clip padded to a shape bucket (``buckets``) is scored
by three compiled stages (``stages``: pixel, pose, finish, each traced from its module), kept in
memory and on disk (``programs``, ``compile_cache``) and called by ``dispatch``.
"""
