"""The character: the DeepMimic humanoid in MuJoCo (its MJCF in ``assets/``) and its kinematics."""
