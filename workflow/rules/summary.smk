# The run's measured test figures as the documentation quotes them (rule summary); copy them into it
# with `python -m hybridfmu.evaluation.measured_blocks results/<case>`.

if "test" in EVAL_ROLES:

    rule summary:
        input:
            test_metrics=f"{RESULTS}/metrics/test.json",
            diagnosis=f"{DIAGNOSIS}/diagnosis.json",
            best=f"{RESULTS}/hpo/best.json",
            time_offset=f"{RESULTS}/evaluation/time_offset.json",
            hybrid_time_offset=HYBRID_TIME_OFFSET,
            truth=truth_files(),
        output:
            summary=f"{RESULTS}/summary.md",
        params:
            case=CASE,
            case_sections=case_sections(),
        log:
            f"{RESULTS}/logs/summary/summary.log",
        script:
            "../scripts/summary.py"

    ALL_TARGETS.append(f"{RESULTS}/summary.md")
