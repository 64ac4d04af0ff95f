# Conveniences; the README's two commands do not need `just`.

# the whole pipeline on the bundled campaign, into reports/
demo:
    cargo run --release

# the test suite's fast tier (release mode: one build profile for everything)
test:
    cargo test --release

# both tiers, as CI runs them (the browser, Python and Dask checks run where
# their tools are; .ci/run makes them mandatory)
test-all:
    cargo test --release -- --include-ignored

# benchmarks of the hot loops; figures go into docs/performance.md
bench:
    cargo bench --bench hot_loops

# regenerate the bundled virtual campaign in data/ (bit for bit)
data:
    cargo run --release -- synth --out data

# validate the bundled campaign
check:
    cargo run --release -- check data/campaign.toml

# the current law on the bundled campaign, calibrated at 0.5 and 1.5 A and
# predicting 1.0 A, then the comparison with the per-current calibrations of
# `just demo` (about 15 min more on 2 cores)
law:
    cargo run --release -- sample data/campaign.toml --model current-law --hold-out-current 1.0 --out reports/rd1005-3-virtual/current-law-without-I1.0A
    cargo run --release -- report reports/rd1005-3-virtual/current-law-without-I1.0A
    cargo run --release -- compare reports/rd1005-3-virtual/I0.5A reports/rd1005-3-virtual/I1.0A reports/rd1005-3-virtual/I1.5A reports/rd1005-3-virtual/current-law-without-I1.0A --out reports/rd1005-3-virtual/comparison

# the replicate study: 100 noise realisations of a virtual 1 A campaign,
# coverage of the credible intervals (docs/calibration.md, docs/studies.md)
coverage:
    cargo run --release -- study plan target/studies/coverage --replicates 100 --cycles 1 --rate 2000
    cargo run --release -- study run target/studies/coverage

# simulation-based calibration, 200 replicates, 2 µm displacement noise
sbc:
    cargo run --release -- study plan target/studies/sbc --sbc 200 --config studies/sbc-prior.toml --rpm 200 --cycles 1 --rate 1000 --noise-displacement 2e-6
    cargo run --release -- study run target/studies/sbc

# the same with the discrepancy model: each replicate draws its discrepancy's
# scale and time scale from their priors too (docs/calibration.md)
sbc-discrepancy:
    cargo run --release -- study plan target/studies/sbc-discrepancy --sbc 200 --config studies/sbc-prior.toml --rpm 200 --cycles 1 --rate 1000 --noise-displacement 2e-6 --noise discrepancy
    cargo run --release -- study run target/studies/sbc-discrepancy

# simulation-based calibration of the bp-spencer law (the B-P element in
# Spencer's frame): 200 campaigns of one revolution at 100, 200, 400 rpm,
# 2 kHz, parameters and noise drawn from studies/sbc-prior-bp-spencer.toml
sbc-bp-spencer:
    cargo run --release -- study plan target/studies/sbc-bp-spencer --sbc 200 --config studies/sbc-prior-bp-spencer.toml --cycles 1 --rate 2000 --noise-displacement 0
    cargo run --release -- study run target/studies/sbc-bp-spencer

# coverage of the between-run layer's new-test intervals: 40 virtual
# populations of five tests whose G and n vary from test to test, four
# calibrated alone, the fifth the new test (docs/calibration.md; needs
# polars: pip install polars)
layer-coverage:
    cargo build --release
    python3 scripts/layer_coverage.py target/release/mrbp target/studies/layer-coverage 40 2

# how much of a held-out record a band for a new test holds: 12 virtual
# dampers tested at three currents, four tests each from a known
# population; the layer's bands (each run and each current left out)
# beside the exact band of the population (docs/calibration.md; about
# 45 min on 2 cores; needs polars and numpy)
current-coverage:
    cargo build --release
    python3 scripts/current_coverage.py target/release/mrbp target/studies/current-coverage 12 2 200

# a new test at currents nobody tested, on 12 virtual dampers whose
# parameters follow curves of shapes mrbp does not assume (tanh, power,
# logistic, piecewise-linear, exponential saturations; G rising or
# falling): calibrated at four currents, tested at five others
# (docs/comparison.md; needs numpy and pandas)
curve-shapes:
    cargo build --release
    python3 scripts/curve_shapes.py target/release/mrbp target/studies/curve-shapes 12 2

# through a switch: the same dampers with a coil lag of 5-30 ms, a run
# switched every 0.1 s between two currents no constant run had,
# predicted by the current curves calibrated without and with a switched
# run (docs/comparison.md; needs numpy, pandas and scipy)
switch-lag:
    cargo build --release
    python3 scripts/switch_lag.py target/release/mrbp target/studies/switch-lag 12 2
