"""Studies of SAMCON (root forces, reference feasibility). They import the product, never the reverse."""
