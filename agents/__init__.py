"""Policies for the ebus-env environments and their evaluation: rule-based ECO baselines
(:mod:`agents.rules`), PPO training and loading (:mod:`agents.ppo`), one score sheet
(:mod:`agents.evaluate`) and the ``ebus train`` / ``ebus evaluate`` commands
(:mod:`agents.commands`). Every policy has ``predict(obs, deterministic=True) -> (action, state)``,
as stable-baselines3's.

The package sits above ``ebus_env``: it imports the environments, never the other way round.
"""
