"""The device front in a table and a plot: the routers that `scripts/results_device.py
router` measured (docs/results-router.json) beside the squaring designs of the stiffness
study (docs/results-stiffness.json), each at 2e-9 kg, 60 dB SPL on 1 mm^2 and 300 K: the
accuracy against the share of the sound the readouts receive, with the loss bound, and the
accuracy with thermal noise against the device's mass."""

from __future__ import annotations

from pathlib import Path

COMMAND = ("python scripts/results_device.py router --data CORPUS --out DIR; "
           "python scripts/results_device.py router-page")


def router_rows(rows: dict) -> list[str]:
    """Per router: its network and ideal-readout accuracy, the readouts' share of the input
    work and of the sound, each readout's k_B T, then each noise study (calibrated for the
    readouts' dark offsets in brackets, where measured) and spread study."""
    out = ["| router | network % (ideal %) | readouts of the work dB | readouts of the sound "
           "dB | each readout k_B T | with noise % (calibrated %), by device mass | mean "
           "device %, by spread |", "|---|---|---|---|---|---|---|"]
    for name, r in rows.items():
        b = r["budget"]
        each = b["stages"]["readouts"]["kt"] / b["readouts"]
        noise = ", ".join(f"{100 * p['accuracy']:.1f}{_calibrated(p)} at "
                          f"{p['device_mass']:g} kg" for p in r.get("noise", []))
        spread = ", ".join(f"{100 * p['mean']:.1f} +- {100 * p['stderr']:.1f} at "
                           f"{p['spread']:g}" for p in r.get("spread", []))
        out.append(f"| {name} | {100 * r['accuracy']:.1f} ({100 * r['ideal']:.1f}) | "
                   f"{b['stages']['readouts']['db_of_work']:.1f} | "
                   f"{b['stages']['readouts']['db_of_sound']:.1f} | {each:.3g} | "
                   f"{noise or '-'} | {spread or '-'} |")
    return out


def _calibrated(point: dict) -> str:
    cal = point.get("calibrated")
    return f" ({100 * cal:.1f})" if cal is not None else ""


def front_plot(routers: dict, squaring: dict, png: Path) -> Path:
    """Two panels: accuracy against the readouts' dB of the sound (the bound drawn), and
    accuracy with thermal noise against device mass, for routers and squaring designs (a
    router's calibrated accuracy dashed, where measured)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 3.8))
    for group, rows, marker in (("router", routers, "o"), ("squaring", squaring, "s")):
        for name, r in rows.items():
            label = f"{group} {name}"
            ax1.scatter([r["budget"]["stages"]["readouts"]["db_of_sound"]],
                        [100 * r["accuracy"]], marker=marker, label=label)
            noise = sorted(r.get("noise", []), key=lambda p: p["device_mass"])
            if noise:
                line, = ax2.plot([p["device_mass"] for p in noise],
                                 [100 * p["accuracy"] for p in noise], marker=marker,
                                 label=label)
            cal = [p for p in noise if p.get("calibrated") is not None]
            if cal:  # the same devices, each readout's dark offset subtracted
                ax2.plot([p["device_mass"] for p in cal], [100 * p["calibrated"] for p in cal],
                         marker=marker, ls="--", color=line.get_color(),
                         label=f"{label}, calibrated")
    bound = next(iter(routers.values()))["budget"]["bound_db"] if routers else 52.9
    ax1.axvline(-bound, color="k", lw=1)
    ax1.text(-bound, 50, f"bound -{bound:.1f} dB ", ha="right")
    ax1.set_xlabel("readouts' energy, dB of the sound (2e-9 kg, 60 dB SPL, 1 mm^2)")
    ax2.set_xscale("log")
    ax2.set_xlabel("device mass (kg), 300 K, 60 dB SPL, 1 mm^2")
    for ax in (ax1, ax2):
        ax.axhline(100 / 12, color="grey", ls=":", lw=1)
        ax.set_ylabel("test accuracy (%)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return png
