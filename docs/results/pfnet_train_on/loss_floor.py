"""The training loss an ideal observation model would reach (docs/pfnet.md, what the loss allows).

PF-net's training draws 30 particles around a perturbed true pose (σ 0.3 m / 30° for the centre
and again for each particle), moves them with exact odometry (each keeps its offset from the
truth) and scores the softmax-weighted mean after each of 25 steps with Δx² + Δy² + 0.36·Δθ².
Here every particle's log-likelihood at a step is −s·d², d² its pose error in those units, so the
model peaks on the truth and is s nats deeper at 1 m than at the truth; s = 0 is the uniform model.

Run: python loss_floor.py (numpy)
"""
import numpy as np

SEQUENCES, PARTICLES, STEPS = 20000, 30, 25
SIGMA_M, SIGMA_RAD, HEADING_WEIGHT = 0.3, np.deg2rad(30.0), 0.36


def loss(depth: float, rng: np.random.Generator) -> float:
    def draw(shape):
        return np.stack([rng.normal(0, SIGMA_M, shape), rng.normal(0, SIGMA_M, shape),
                         rng.normal(0, SIGMA_RAD, shape)], axis=-1)
    particles = draw((SEQUENCES, 1)) + draw((SEQUENCES, PARTICLES))
    d2 = particles[..., 0] ** 2 + particles[..., 1] ** 2 + HEADING_WEIGHT * particles[..., 2] ** 2
    per_step = []
    for t in range(1, STEPS + 1):
        loglik = -t * depth * d2  # weights accumulate over the steps, as in training
        w = np.exp(loglik - loglik.max(axis=1, keepdims=True))
        w /= w.sum(axis=1, keepdims=True)
        mean = (w[..., None] * particles).sum(axis=1)
        per_step.append((mean[:, 0] ** 2 + mean[:, 1] ** 2 + HEADING_WEIGHT * mean[:, 2] ** 2).mean())
    return float(np.mean(per_step))


if __name__ == "__main__":
    rng = np.random.default_rng(0)
    for depth in [0.0, 0.5, 1.0, 2.0, 5.0, 10.0, 30.0]:
        print(f"depth {depth:5.1f} nats/m² per step: loss {loss(depth, rng):.4f}")
