#!/usr/bin/env bash
# Regenerate every figure of docs/ from a clean checkout: run the shipped studies, draw their
# figures from the archives, and copy the ones docs/results.md shows into docs/figures/.
# Usage: pipelines/figures.sh [RESULTS_DIR]   (default: results; about 2 minutes on 2 cores)
set -euo pipefail
cd "$(dirname "$0")/.."
results="${1:-results}"

# every shipped study but round_off (1e8 steps, ~20 core-minutes): pipelines/bench_round_off.py
# runs it and draws its figure
configs=()
for config in configs/*.yaml; do
    [[ "$config" == configs/round_off.yaml ]] || configs+=("$config")
done
rbstudy sweep "${configs[@]}" --out "$results" --quiet
for config in "${configs[@]}"; do
    study="$(basename "$config" .yaml)"
    rbstudy plot "$results/$study/$study.nc"       # into $results/$study/figures/
done
rbstudy report "$results/abaqus_top/abaqus_top.nc"  # into $results/abaqus_top/report/

# study:figure pairs shown in docs/results.md
shown=(
    abaqus_top:convergence_orientation abaqus_top:work_precision
    abaqus_top:benchmark_omega_time abaqus_top:benchmark_omega_xy abaqus_top:benchmark_node_path
    abaqus_top:convergence_precession
    convergence_asymmetric:convergence_orientation convergence_asymmetric:work_precision
    high_spin:stability_map stiff_inertia:stability_map
    long_run:invariant_drift long_run_convergence:convergence_orientation
    intermediate_axis:convergence_orientation
    hht_damping:convergence_orientation spin_tilt:stability_map
    radioss_body:convergence_orientation radioss_spin_limit:stability_map
    high_order:convergence_orientation high_order:work_precision
    heavy_top:convergence_orientation published_steps:work_precision
)
mkdir -p docs/figures
for pair in "${shown[@]}"; do
    study="${pair%%:*}"
    figure="${pair#*:}"
    cp "$results/$study/figures/${study}_${figure}.png" "docs/figures/${study}_${figure}.png"
done
echo "docs/figures: ${#shown[@]} figures from $results"
