"""Motion clips: reading, the kinematic reference library, the HDF5 dataset, import (BVH) and ``mimic-motions``."""
