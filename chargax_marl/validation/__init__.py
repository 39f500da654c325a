"""Charging sessions against real ones: the ACN-Data sessions the session model is fitted to
(`real`), the fit (`fit`), the simulator's sessions (`simulated`) and the held-out comparison
(`report`; ``python -m chargax_marl.validation``)."""
