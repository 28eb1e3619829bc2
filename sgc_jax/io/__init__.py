"""Clip files and score tables: the clip schema and writing (``clip``), reading and clip sources
(``loading``, ``npz``, ``remote``), content checks (``validate``; depth given as range: ``depth_range``), and tables on disk and on screen
(``tables``, ``parquet``). Nothing here computes a score.
"""
