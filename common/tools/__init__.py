"""Tools above every layer of common/: the mimic-motions command and offscreen rendering."""
