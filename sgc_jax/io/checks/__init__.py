"""The content checks of a clip, a module per part of it; :mod:`sgc_jax.io.validate` runs them in order.

problems     a finding (:class:`~.problems.Problem`), its severities, and the error and warning it becomes
motion_fits  how well the tracks fit the cameras' motion with poses, tracks or depth read one way or another
cameras      intrinsics, focal lengths over the frames, rotations, the pose file's convention
tracks       positions, extent, axes and scale, confidence, visibility, repeats, the clip's length
depth        valid depth, sign, far backdrop, ramps and blended holes, depth against disparity and range
masks        the static mask's coverage, and an inverted mask
visibility   visibility stored the other way round (an occlusion flag)
stored       stored dtypes and value sets
"""
