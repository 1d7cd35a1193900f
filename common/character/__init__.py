"""The character: the DeepMimic humanoid in MuJoCo (its MJCF in ``assets/``), its kinematics and its state."""
