"""Studies: measurements and experiments around the trackers. They import the product, never the reverse."""
