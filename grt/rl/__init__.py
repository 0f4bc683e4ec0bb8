"""Learning for GRT tasks: rsl-rl's VecEnv over task sessions, PPO training, point-cloud models."""
