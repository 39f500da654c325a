#!/bin/bash
# The ablation tables of results/ablation/ from its score files (run from the repository root).
set -euo pipefail
S=results/ablation/scores
PY=${PY:-.venv/bin/python}
$PY -m baselines.analysis.ablation --task Chargax-shopping-grid10-high-v1 --rules edf \
  --base "IPPO, make train's config (car plan teacher, one level per direction)=$S/grid10_base.json" \
  --method "IPPO, no car teacher=$S/grid10_no_teacher.json" \
  --method "IPPO, coupled teacher (shaping and advice)=$S/grid10_coupled.json" \
  --method "IPPO, priority classes (1), no teacher=$S/grid10_classes1.json" \
  --method "IPPO, priority classes (2), no teacher=$S/grid10_classes2.json" \
  --method "MAPPO, priority classes (1), no teacher=$S/grid10_mappo_classes1.json" \
  --method "IPPO, priority classes (1), coupled advice=$S/grid10_classes1_coupled_obs.json" \
  --out results/ablation/grid10 > /dev/null
for spec in "shopping-v1:shopping" "shopping-grid25-high-v1:grid25" "shopping-peak-v1:peak"; do
    task=${spec%%:*}; name=${spec##*:}
    extra=()
    if [ "$name" = shopping ]; then
      extra=(--method "IPPO, priority classes (1), car plan teacher=$S/shopping_classes1.json"
             --method "IPPO, priority classes (1), no teacher=$S/shopping_classes1_no_teacher.json")
    else
      extra=(--method "IPPO, priority classes (1), no teacher=$S/${name}_classes1.json")
    fi
    $PY -m baselines.analysis.ablation --task Chargax-$task --rules edf \
      --base "IPPO, make train's config=$S/${name}_base.json" "${extra[@]}" \
      --out results/ablation/$name > /dev/null
done
$PY -m baselines.analysis.ablation --task Chargax-shopping-v3 --rules coupled_plan \
  --base "IPPO, the ippo_residual config without the residual=$S/shopping_v3_no_residual.json" \
  --method "IPPO, residual over the coupled plan (ippo_residual)=$S/shopping_v3_residual.json" \
  --method "IPPO, the ippo config (one level per direction, car plan teacher)=results/scores/ippo_Chargax-shopping-v3.json" \
  --method "IPPO, residual with the battery distilled from the MPC (ippo_distill)=results/scores/ippo_distill_Chargax-shopping-v3.json" \
  --method "IPPO, the same with the station's demand observed (ippo_distill, STATION_OBS)=results/scores/ippo_distill_station_Chargax-shopping-v3.json" \
  --out results/ablation/shopping_v3 > /dev/null
