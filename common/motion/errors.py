"""The error every motion reader raises (clips, clip packs, motion datasets, BVH, joint maps)."""


class MotionFormatError(ValueError):
    """A motion file that cannot be read; the message names the file, the frame and the problem, on one line."""
