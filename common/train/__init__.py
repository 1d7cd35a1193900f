"""The training loop both learners share (budgets, periodic evaluation, resume) and policy weight averaging."""
