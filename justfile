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
