"""Policies for the environments and their evaluation: rule-based ECO baselines
(:mod:`~ebus_env.agents.rules`), PPO (:mod:`~ebus_env.agents.ppo`) and one score sheet
(:mod:`~ebus_env.agents.evaluate`). Every policy has ``predict(obs, deterministic=True) ->
(action, state)``, as stable-baselines3's."""
