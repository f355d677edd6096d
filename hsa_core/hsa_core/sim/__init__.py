"""The simulated world and runs on it: world, disturbance, run conditions, the offline experiment,
the batched JAX loop and the lockstep decisions."""
