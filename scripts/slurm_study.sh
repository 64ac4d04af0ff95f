#!/usr/bin/env bash
# An mrbp study as a Slurm job array: array element i runs task i of the
# study (line i + 1 of STUDY/tasks.csv). The study folder must be on a file
# system every node sees; `mrbp` on the PATH or in $MRBP.
#
#   n=$(($(wc -l < STUDY/tasks.csv) - 1))
#   job=$(sbatch --parsable --array=1-"$n"%64 scripts/slurm_study.sh STUDY)
#   sbatch --dependency=afterany:"$job" --wrap "mrbp study collect STUDY"
#
# A preempted or failed element can be run again (sbatch --array=LIST, or
# --requeue): a finished task is skipped and an interrupted one resumes from
# its checkpoint. SIGTERM at the time limit makes mrbp save a checkpoint
# and exit 130.
#SBATCH --job-name=mrbp-study
#SBATCH --cpus-per-task=2
#SBATCH --time=01:00:00
#SBATCH --requeue
#SBATCH --output=mrbp-study-%A_%a.log
set -euo pipefail
study="${1:?usage: slurm_study.sh STUDY_FOLDER}"
index="${SLURM_ARRAY_TASK_ID:?not in a Slurm job array (set SLURM_ARRAY_TASK_ID to run one task by hand)}"
task=$(sed -n "$((index + 1))p" "$study/tasks.csv")
if [ -z "$task" ]; then
    echo "slurm_study.sh: no task $index in $study/tasks.csv" >&2
    exit 2
fi
exec "${MRBP:-mrbp}" --threads "${SLURM_CPUS_PER_TASK:-1}" study run-task "$study" "$task"
