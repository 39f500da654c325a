"""The trainers (PPO, IPPO, MAPPO) and what they are made of: networks, the PPO core, the
chunked runner. They import only `baselines.config` and `chargax_marl`."""
