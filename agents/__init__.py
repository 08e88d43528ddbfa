"""Policies for the environments and their evaluation: rule-based ECO baselines
(:mod:`~agents.rules`), PPO (:mod:`~agents.ppo`) and one score sheet
(:mod:`~agents.evaluate`). Every policy has ``predict(obs, deterministic=True) ->
(action, state)``, as stable-baselines3's."""
