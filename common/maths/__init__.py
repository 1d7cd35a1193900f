"""Rotation maths: quaternions, matrices and angles in numpy and, differentiable, in torch."""
