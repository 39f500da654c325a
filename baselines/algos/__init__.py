"""The trainers (PPO, IPPO, MAPPO) and what they are made of: networks, the PPO core, the
chunked runner. They import only :mod:`baselines.config` and :mod:`chargax_marl`."""
