#!/bin/bash
# A phase-space map on a Slurm cluster: one array task per shard, then one merge job.
#
#   examples/slurm/map-array.sh CONFIG.toml OUT_DIR [SHARDS]
#
# submits (from a login node)
#   1. an array job of SHARDS tasks; task i runs `chaoscope map CONFIG --shard i/SHARDS`
#      into OUT_DIR/shard-i.mcap with all the CPUs Slurm gave it;
#   2. a merge job, started only when every task succeeded (afterok), that joins the shards
#      into OUT_DIR/map.mcap and OUT_DIR/map.png.
# A task that is preempted or hits its time limit is simply resubmitted (Slurm's --requeue, or
# by hand: `sbatch --array=<i> ...`): `chaoscope map` resumes from its shard's recording.
#
# Environment: CHAOSCOPE (path of the binary, default: `chaoscope` on PATH); the resources of
# each array task: CPUS_PER_TASK (default 4), MEM_PER_CPU (500M), TIME_LIMIT (02:00:00); and the
# usual sbatch settings (SBATCH_PARTITION, SBATCH_ACCOUNT, ...).
set -euo pipefail

if [[ $# -lt 2 ]]; then
    sed -n '2,15p' "$0" >&2
    exit 2
fi
CONFIG=$(realpath "$1")
OUT=$(realpath -m "$2")
SHARDS=${3:-16}
CHAOSCOPE=${CHAOSCOPE:-$(command -v chaoscope || echo chaoscope)}
mkdir -p "$OUT/logs"

# Shard i of n holds the grid points with index % n == i, so every task gets the same mix of
# fast (chaotic, stopping early) and slow (regular) points and the tasks finish together.
array_job=$(sbatch --parsable \
    --job-name=chaoscope-map \
    --array=0-$((SHARDS - 1)) \
    --cpus-per-task="${CPUS_PER_TASK:-4}" \
    --mem-per-cpu="${MEM_PER_CPU:-500M}" \
    --time="${TIME_LIMIT:-02:00:00}" \
    --requeue \
    --output="$OUT/logs/shard-%a.out" \
    --wrap="'$CHAOSCOPE' map '$CONFIG' --shard \$SLURM_ARRAY_TASK_ID/$SHARDS \
            --out '$OUT'/shard-\$SLURM_ARRAY_TASK_ID.mcap \
            --threads \${SLURM_CPUS_PER_TASK:-1} --no-progress --json")

merge_job=$(sbatch --parsable \
    --job-name=chaoscope-merge \
    --dependency=afterok:$array_job \
    --cpus-per-task=1 \
    --mem=2G \
    --time=00:20:00 \
    --output="$OUT/logs/merge.out" \
    --wrap="'$CHAOSCOPE' merge '$OUT'/shard-*.mcap --out '$OUT'/map.mcap --png '$OUT'/map.png --force --json")

echo "submitted array job $array_job ($SHARDS shards) and merge job $merge_job"
echo "array_job=$array_job merge_job=$merge_job"
echo "results: $OUT/map.mcap, $OUT/map.png"
