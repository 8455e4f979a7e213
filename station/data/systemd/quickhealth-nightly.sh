#!/bin/sh
# quickhealth nightly: measure the robot, fit the run, archive it, report it, judge the trend.
#
# Settings come from the environment (systemd: EnvironmentFile=/etc/quickhealth/nightly.env;
# cron: `. /etc/quickhealth/nightly.env` first), see nightly.env.example:
#   QH_ROBOT QH_CELL QH_PLAN QH_ROBOT_IP QH_CALIBRATION QH_RUNS QH_ARCHIVE   (required)
#   QH_DB (shared index URL)  QH_THRESHOLD_MM (the accuracy spec, mm, instead of the cell's
#   spec_mm)  QH_ROBOT_MODEL (ur5)  QH_BIN (quickhealth)
#   QH_MODE: "run" (default: the full loop every night) or "check": first the quick check
#   against the archive's baseline (recorded in the archive as a check); only when it says
#   "changed" does the full loop run, fitted, archived and judged as above
#
# Exit status, the first failing step's (the later steps do not run):
#   0 run archived, trend healthy     1 the trend flagged the robot
#   2 bad input (a setting, a file)   3 hardware or runtime failure (robot, cameras, motor,
#                                       run lock held, archive or index unreachable)
# Progress goes to stdout (the journal under systemd, the log file under cron) and to
# RUN_DIR/run.log; the report (its verdict, the one every door shows) to RUN_DIR/report.html,
# report.pdf and report.json; the trend to RUN_DIR/trend.json and trend.png.
set -u
missing=""
for v in QH_ROBOT QH_CELL QH_PLAN QH_ROBOT_IP QH_CALIBRATION QH_RUNS QH_ARCHIVE; do
    eval "[ -n \"\${$v:-}\" ]" || missing="$missing $v"
done
if [ -n "$missing" ]; then
    echo "quickhealth-nightly: error: not set:$missing (see nightly.env.example)" >&2
    exit 2
fi
QH=${QH_BIN:-quickhealth}
run_dir="$QH_RUNS/$(date -u +%Y-%m-%dT%H%M%SZ)"
set -- --archive "$QH_ARCHIVE"
[ -n "${QH_DB:-}" ] && set -- "$@" --db "$QH_DB"
case "${QH_MODE:-run}" in
    run) ;;
    check)
        check_dir="$QH_RUNS/check-$(date -u +%Y-%m-%dT%H%M%SZ)"
        echo "quickhealth-nightly: robot $QH_ROBOT, quick check in $check_dir"
        "$QH" check --cell "$QH_CELL" --plan "$QH_PLAN" --robot "$QH_ROBOT" "$@" \
            --out "$check_dir" --robot-ip "$QH_ROBOT_IP" --calibration "$QH_CALIBRATION" \
            --unattended
        status=$?
        [ "$status" -eq 1 ] || exit "$status"   # unchanged (0), or a failure: done tonight
        echo "quickhealth-nightly: the quick check says changed: the full assessment follows"
        ;;
    *)
        echo "quickhealth-nightly: error: QH_MODE must be run or check, not $QH_MODE" >&2
        exit 2
        ;;
esac
echo "quickhealth-nightly: robot $QH_ROBOT, run folder $run_dir"
"$QH" run --cell "$QH_CELL" --plan "$QH_PLAN" --out "$run_dir" --robot-ip "$QH_ROBOT_IP" \
    --calibration "$QH_CALIBRATION" --unattended --robot-name "$QH_ROBOT" || exit $?
"$QH" identify fit "$run_dir/measurements.csv" --robot "${QH_ROBOT_MODEL:-ur5}" \
    --out "$run_dir" || exit $?
"$QH" archive add "$run_dir" --robot "$QH_ROBOT" "$@" || exit $?
if [ -n "${QH_THRESHOLD_MM:-}" ]; then
    set -- "$@" --threshold-mm "$QH_THRESHOLD_MM"
fi
"$QH" report "$run_dir" --robot "$QH_ROBOT" "$@" || exit $?
exec "$QH" trend "$QH_ROBOT" "$@" --json "$run_dir/trend.json" --plot "$run_dir/trend.png"
