"""Rule train_rung: one configuration trained through one Hyperband rung (resumed from the previous rung).

The job holds a lock on its output (an orphan of a killed workflow still writing it is stopped first),
stops itself when the Snakemake process that started it is gone, and treats SIGTERM as an interrupt.
"""

from pathlib import Path

import torch

from hybridfmu.api.stages import case_roles, job_guard, retry_settings, run_trial_rung, setup_rule_logging

# intra-op threads: the job's share of the cores (rule train_rung's threads), not torch's default of all cores
torch.set_num_threads(max(1, int(snakemake.threads)))
setup_rule_logging(snakemake.log[0])
label = f"train_rung {snakemake.wildcards.search} b{snakemake.wildcards.bracket} r{snakemake.wildcards.rung} c{snakemake.wildcards.config}"
with job_guard(Path(snakemake.output.checkpoint).with_name("job.lock"), label):
    run_trial_rung(
        plan_path=snakemake.input.plan,
        bracket=int(snakemake.wildcards.bracket),
        rung=int(snakemake.wildcards.rung),
        config_index=int(snakemake.wildcards.config),
        train_arrays_path=snakemake.input.train,
        validation_arrays_path=snakemake.input.validation,
        statistics_path=snakemake.input.statistics,
        fmu_path=snakemake.input.fmu,
        calibration_path=snakemake.input.calibration,
        roles=case_roles(snakemake.params.case),
        model_config=snakemake.params.model,
        training_config=snakemake.params.training,
        previous_checkpoint=snakemake.input.previous or None,
        checkpoint_path=snakemake.output.checkpoint,
        result_path=snakemake.output.result,
        tracking_options=retry_settings(snakemake.config.get("mlflow")),
        rung_logging=(snakemake.config.get("mlflow") or {}).get("rung_logging", "each_job"),
        diagnosed_path=snakemake.input.diagnosed[0] if snakemake.input.diagnosed else None,
        physical_layer_rollout_path=snakemake.input.shared_rollout[0] if snakemake.input.shared_rollout else None,
    )
