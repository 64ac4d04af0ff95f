# Conveniences; the README's two commands do not need `just`.

# the whole pipeline on the bundled campaign, into reports/
demo:
    cargo run --release

# the test suite (release mode: one build profile for everything)
test:
    cargo test --release

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
