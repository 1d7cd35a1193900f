"""Generalised advantage estimation (Schulman et al. 2016) over a rollout of N characters, with episode ends.

For step t with value v_t = V(s_t), the value of what follows the step is

    next_t = 0                    if the episode terminated at t (a failure: nothing follows),
    next_t = bootstrap_t          if it was truncated at t (time limit: V of the state the step reached),
    next_t = v_{t+1}              otherwise (``last_values`` after the last step),

and delta_t = r_t + gamma next_t - v_t, A_t = delta_t + gamma lambda (1 - done_t) A_{t+1}, returns R_t = A_t + v_t.
"""

from __future__ import annotations

import numpy as np


def gae(
    rewards: np.ndarray,
    values: np.ndarray,
    last_values: np.ndarray,
    terminated: np.ndarray,
    truncated: np.ndarray,
    bootstrap_values: np.ndarray,
    gamma: float,
    lam: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Advantages and value targets of a rollout.

    Args:
        rewards: Reward of each step. Shape: (T, N).
        values: V(s_t) of the state each step started from. Shape: (T, N).
        last_values: V(s_T) of the state after the last step (the next rollout's first state). Shape: (N,).
        terminated: The episode failed at this step. Shape: (T, N).
        truncated: The episode hit a time limit at this step. Shape: (T, N).
        bootstrap_values: V of the state a truncated step reached (ignored where not truncated). Shape: (T, N).
        gamma: Discount per step.
        lam: GAE lambda.

    Returns:
        advantages (T, N) and returns (T, N), float64.
    """
    T, N = rewards.shape
    for name, x in (("values", values), ("terminated", terminated), ("truncated", truncated),
                    ("bootstrap_values", bootstrap_values)):  # fmt: skip
        if x.shape != (T, N):
            raise ValueError(f"gae: {name} has shape {x.shape}, expected {(T, N)}")
    if last_values.shape != (N,):
        raise ValueError(f"gae: last_values has shape {last_values.shape}, expected {(N,)}")
    terminated = terminated.astype(bool)
    truncated = truncated.astype(bool) & ~terminated
    next_values = np.concatenate([values[1:], last_values[None]], axis=0).astype(np.float64)
    next_values = np.where(truncated, bootstrap_values, next_values)
    next_values = np.where(terminated, 0.0, next_values)
    deltas = rewards + gamma * next_values - values
    carry = (~(terminated | truncated)).astype(np.float64) * gamma * lam
    advantages = np.zeros((T, N), dtype=np.float64)
    running = np.zeros(N, dtype=np.float64)
    for t in range(T - 1, -1, -1):
        running = deltas[t] + carry[t] * running
        advantages[t] = running
    return advantages, advantages + values
