"""`springc tune`: end-to-end tuning of a mass-spring keyword spotter through its network."""

from __future__ import annotations

from pathlib import Path

import click
from springc_cli.common import run_user_errors

_GROUPS = "filter,compression,couplings,readout"


@click.command("tune")
@click.argument("model", type=click.Path(path_type=Path))
@click.option("--data", type=click.Path(path_type=Path), default=None,
              help="Data set folder (default: the one the model was trained on).")
@click.option("-o", "--out", required=True, type=click.Path(path_type=Path),
              help="New model folder for the tuned model.")
@click.option("--params", default=_GROUPS, show_default=True,
              help="Parameter groups to tune: filter (per-bin Mel filter frequency), "
                   "compression (per-bin compressor stiffness), couplings (each head's "
                   "quadratic couplings), readout (each head's intercept).")
@click.option("--refit/--no-refit", default=True, show_default=True,
              help="First refit each head's weights and intercept on the transferred "
                   "network's exact response (an SVM on its zero modes' integrals, C on the "
                   "validation split): forward simulations only.")
@click.option("--refit-clips", default=0, show_default=True,
              help="Training clips the refit simulates, drawn with --seed (0: all).")
@click.option("--epochs", default=2, show_default=True,
              help="Passes of gradient steps over the clips (0: the refit alone).")
@click.option("--batch", default=16, show_default=True, help="Clips per optimiser step.")
@click.option("--clips", default=64, show_default=True,
              help="Training clips tuned on, drawn with --seed (0: all).")
@click.option("--val-clips", default=64, show_default=True,
              help="Validation clips whose loss picks the epoch kept (the start included; "
                   "0: keep the last).")
@click.option("--lr", default=0.05, show_default=True, help="Adam step size on the variables.")
@click.option("--il-weight", default=0.0, show_default=True,
              help="Loss weight per dB of mean insertion loss (0: accuracy alone).")
@click.option("--mc", "devices", default=0, show_default=True, metavar="N",
              help="Fabricated devices the loss is averaged over (with --spread): N new ones "
                   "at every step, and a fixed N for the validation loss (0: the nominal "
                   "network alone).")
@click.option("--spread", default=0.0, show_default=True, metavar="S",
              help="With --mc: relative spread of every coefficient of a device.")
@click.option("--seed", default=0, show_default=True,
              help="Clip draw, batch order and the devices' draws.")
@click.option("--jobs", "-j", default=0, help="Worker processes (0: all cores).")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Dask scheduler to send the batches to (default: a local cluster).")
@run_user_errors
def tune_cmd(model, data, out, params, refit, refit_clips, epochs, batch, clips, val_clips,
             lr, il_weight, devices, spread, seed, jobs, scheduler):
    """Tune MODEL (trained with --realisation mass-spring or device) through its simulated
    network: the heads' weights refitted on the network's exact response (the paper's heads
    only), then softmax cross-entropy of the readouts' decisions at a learnt temperature
    (plus --il-weight x insertion loss), averaged over --mc fabricated devices where given,
    gradients by the discrete adjoint at RK4 x8, Adam; keeps the epoch with the lowest
    validation loss; every tuned netlist passes the checks. Writes OUT like train
    (netlists, settings, report of the test split, README); the parameters are saved
    beside OUT after every epoch and a rerun resumes from them."""
    from springc.kws.training.readme import tune_history_text
    from springc.kws.tuning.tune import tune_model

    report = tune_model(model, out, data=data,
                        params=tuple(p.strip() for p in params.split(",") if p),
                        epochs=epochs, batch=batch, clips=clips, val_clips=val_clips, lr=lr,
                        il_weight=il_weight, mc=devices, spread=spread, seed=seed, jobs=jobs,
                        scheduler=scheduler, refit=refit, refit_clips=refit_clips)
    click.echo(f"tuned {', '.join(report['tune']['params'])}: "
               f"{tune_history_text(report['tune'])}")
    if "accuracy" in report:
        click.echo(f"test accuracy {100 * report['accuracy']:.1f}% (n={report['n']}), "
                   f"insertion loss {report['insertion_loss_db']['median']:.1f} dB median")
    click.echo(f"model written to {out}")


COMMANDS = [tune_cmd]
