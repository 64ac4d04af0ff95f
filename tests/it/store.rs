//! Every file of a results folder read back by the module that writes it:
//! a whole `mrbp run` on two currents, then each store module's reader
//! agrees with what the run said and with the other files.

use std::path::Path;

use crate::common::{arg, ok, write_virtual};

use mrbp::store;
use mrbp::synth::SynthSettings;

#[test]
fn every_file_reads_back_and_agrees_with_the_others() {
    let data = tempfile::tempdir().unwrap();
    let settings = SynthSettings {
        currents_a: vec![0.5, 1.0],
        rpms: vec![200.0, 400.0],
        cycles: 1.0,
        rate_hz: 1000.0,
        ..SynthSettings::default()
    };
    let manifest = write_virtual(&settings, data.path());
    let out = tempfile::tempdir().unwrap();
    ok(&[
        "run",
        arg(&manifest),
        "--out",
        arg(out.path()),
        "--substeps",
        "2",
        "--steps",
        "40",
        "--draws",
        "50",
    ]);

    for current in ["I0.5A", "I1.0A"] {
        let dir = out.path().join(current);
        let cal = store::folder::read(&dir).unwrap();
        assert_eq!(cal.record.runs.len(), 2);
        assert_eq!(cal.summary.len(), cal.sample.layout.names.len());

        let prediction = store::prediction::read(&dir).unwrap().expect("a prediction");
        assert_eq!(prediction.record.calibration_id, cal.record.calibration_id);
        assert_eq!(prediction.bands.len(), 2);
        assert_eq!(prediction.adequacy.len(), 2);
        for (a, c) in prediction.adequacy.iter().zip(&prediction.coverage) {
            assert_eq!(a.run, c.run);
            // adequacy counts the first sample too, coverage does not
            assert!(
                (a.inside_p95 - c.inside_p95).abs() <= 1.0 / c.samples as f64,
                "{} vs {}",
                a.inside_p95,
                c.inside_p95
            );
        }

        let identification =
            store::identification::read(&dir.join(store::identification::FILE)).unwrap();
        let g = identification
            .iter()
            .find(|r| r.run == "all" && r.parameter == "G")
            .expect("the combined G");
        assert_eq!(g.value, cal.record.identification["G"]);

        let stored = store::inference::read(&dir.join(store::inference::FILE)).unwrap();
        assert_eq!(stored.calibration_id, cal.record.calibration_id);
        let names: Vec<&str> = stored.posterior.iter().map(|(n, _)| n.as_str()).collect();
        for n in &cal.sample.layout.names {
            assert!(names.contains(&n.as_str()), "{n} not in the posterior group");
        }
        // the posterior group holds the chains' last draws, chain by chain
        let chains = &cal.sample.chains;
        let first = stored.draws[0] as usize;
        let (name, values) = &stored.posterior[names.iter().position(|n| *n == "G").unwrap()];
        let draws = stored.draws.len();
        for c in [0, chains.chains() - 1] {
            assert_eq!(values[c * draws], chains.at(first, c, 0), "{name} of chain {c}");
        }
        let (nc, nd, nobs) = stored.pointwise_shape;
        assert_eq!(nc, chains.chains());
        assert_eq!(stored.log_likelihood.len(), nc * nd * nobs);
        assert!(stored.log_likelihood.iter().all(|v| v.is_finite()));
    }

    let comparison = store::comparison::read(&out.path().join("comparison")).unwrap();
    let calibrations: std::collections::BTreeSet<&str> =
        comparison.rows.iter().map(|r| r.calibration.as_str()).collect();
    assert_eq!(calibrations.into_iter().collect::<Vec<_>>(), ["I0.5A", "I1.0A"]);
    let r0 = comparison.differences.iter().find(|d| d.parameter == "R0").expect("R0 compared");
    assert!((0.0..=1.0).contains(&r0.difference.p_greater));
    assert!(Path::new(&out.path().join("comparison").join(mrbp::report::html::REPORT)).is_file());
}
