"""The text and picture of a station state at its clock time (`chargax_marl.rendering`)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from chargax_marl import rendering
from chargax_marl.core import make_params, simulator


def test_the_text_shows_the_clock_time_and_its_price():
    p = make_params(episode_start_hour=12)
    start = simulator.empty_state(jnp.int32(3), p)
    prices = np.asarray(p.prices_eur_kwh)
    assert rendering.clock_time(start, p) == "12:00"
    assert rendering.price_now(start, p) == float(prices[3, 12])
    after = start.replace(timestep=jnp.int32(150))  # 12:30 past noon
    assert rendering.clock_time(after, p) == "00:30 (+1 day)"
    assert rendering.price_now(after, p) == float(prices[4, 0])
    midnight = make_params()
    end = simulator.empty_state(jnp.int32(3), midnight).replace(timestep=jnp.int32(288))
    assert rendering.clock_time(end, midnight) == "24:00"


def test_the_plot_draws_clock_hours():
    p = make_params(episode_start_hour=12)
    state = simulator.empty_state(jnp.int32(3), p)
    image = rendering.rgb_plot([(0.0, 0.1, 5.0), (13.0, 0.2, 7.0)], state, p)
    assert image.ndim == 3 and image.shape[2] == 3 and image.dtype == np.uint8


def test_the_text_rendering_counts_the_steps_of_a_multi_day_episode():
    """A two-day episode's state reads ``step t/(2 * num_steps)``, not of one day."""
    import jax

    from chargax_marl.core import make_params, simulator
    from chargax_marl.rendering import ansi_table

    params = make_params(episode_days=2)
    state = simulator.reset(jax.random.PRNGKey(0), params)
    names = [f"port_{i}" for i in range(params.station.num_ports)] + ["battery_0"]
    assert f"step 0/{2 * params.num_steps}" in ansi_table(state, params, names)
