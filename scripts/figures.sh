#!/usr/bin/env bash
# Regenerates every figure and table under docs/ (see docs/results.md), one `impm study` per
# figure. Usage: scripts/figures.sh [all|fig2|fig3|where]   (about a minute in release on 2 cores)
#
# Each study writes DIR/study.csv, DIR/study.md, the charts (.svg and .png) and runs/ (every
# run's own output, deleted here to keep docs/ small).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet
IMPM=target/release/impm
SCENE=scripts/column_1d.rhai
CELLS=5,10,20,50,100,200,400

# The methods of Fig. 3, one per line as basis:order:ppc:placement:integration (order is ignored
# by methods without one, integration by all but bspline). Adding a method is adding its line.
# GIMP is the scene default (stretched domains); GIMP and CPDI use 2 points per cell. The last
# four are the options for the paper's closing question: Gauss placement, and B-splines
# averaged over the point domains.
METHODS=(
  bspline:2:4:uniform:points
  bspline:3:4:uniform:points
  bspline:4:4:uniform:points
  bspline:4:8:uniform:points
  linear:1:1:uniform:points
  gimp:1:2:uniform:points
  cpdi:1:2:uniform:points
  fem:1:2:uniform:points
  bspline:3:4:gauss:points
  bspline:2:4:uniform:domain
  bspline:3:4:uniform:domain
  bspline:4:4:uniform:domain
)

study() { # OUT ARGS...: run one study into docs/OUT and drop the per-run files
  local out=docs/$1; shift
  rm -rf "$out"
  "$IMPM" study "$SCENE" --out "$out" "$@"
  rm -rf "$out/runs"
}

what=${1:-all}
if [[ $what == all || $what == fig2 ]]; then
  # Fig. 2: stress along the column, linear MPM (1 point per cell) and cubic B-spline MPM
  # (4 points per cell), 50 cells, 20 load steps, for W = 10000, 40000 and 400000.
  for bf in 200 800 8000; do
    study "fig2/W$((bf * 50))" --sweep basis=linear,bspline --set "body_force=-$bf" --profiles
  done
fi
if [[ $what == all || $what == fig3 ]]; then
  # Fig. 3 and the accuracy-cost front: eq. 15 error against cells and against wall time.
  methods=$(IFS=,; echo "${METHODS[*]}")
  for bf in 200 8000; do
    study "fig3/W$((bf * 50))" --sweep "basis:order:ppc:placement:integration=$methods" \
      --sweep "cells=$CELLS" --set "body_force=-$bf"
  done
fi
if [[ $what == all || $what == where ]]; then
  # Where B-spline MPM loses accuracy: the pointwise error along the column at three
  # resolutions (cubic, 4 points per cell, W = 10000), raw and MLS-recovered, for the regular
  # lattice, for Gauss placement and for the basis averaged over the point domains; and the
  # rates of raw and recovered stress for the three.
  for variant in uniform:points gauss:points uniform:domain; do
    placement=${variant%:*} integration=${variant#*:}
    name=$placement; [[ $integration == domain ]] && name=domain
    study "where/$name" --sweep cells=10,40,160 --set placement=$placement \
      --set integration=$integration --set body_force=-200 --set recovery=mls --profiles
  done
  study "where/rates" --sweep "placement:integration=uniform:points,gauss:points,uniform:domain" \
    --sweep order=2,3,4 --sweep "cells=$CELLS" --set body_force=-200 --set recovery=mls
fi
