//! Effort sequence parser and player.
#![allow(clippy::needless_range_loop)]

use hap_core::effort::*;
use hap_core::fixed::Fx;
use proptest::prelude::*;

const GOOD: &[u8] = b"# hapticctrl effort sequence\n\
# t_ms fx fy fz tx ty tz [deadman [b1 [b2]]]\n\
\n\
0     0    0    0     0 0 0     1\r\n\
500   2.5  0   -1.25  0 0 0.05  1 0 0   # push forward\n\
\t1500  +0.0004 -0.0005 1000 -1000 0.9999 0.1234567 0 1 1\n\
2000  0 0 0 0 0 0";

fn parse(t: &[u8]) -> Result<Vec<EffortKeyframe>, EffortParseError> {
    let mut out = [EffortKeyframe::ZERO; 16];
    parse_effort_sequence(t, &mut out).map(|n| out[..n].to_vec())
}

fn err(t: &[u8]) -> (u32, u32, EffortErrorKind) {
    let e = parse(t).unwrap_err();
    (e.line, e.column, e.kind)
}

#[test]
fn good_file() {
    let k = parse(GOOD).unwrap();
    assert_eq!(k.len(), 4);
    assert_eq!(
        k[0],
        EffortKeyframe {
            t_ms: 0,
            force_mn: [0; 3],
            torque_mnm: [0; 3],
            flags: FLAG_DEAD_MAN
        }
    );
    assert_eq!(k[1].t_ms, 500);
    assert_eq!(k[1].force_mn, [2500, 0, -1250]);
    assert_eq!(k[1].torque_mnm, [0, 0, 50]);
    assert_eq!(k[2].force_mn, [0, -1, 1_000_000]);
    assert_eq!(k[2].torque_mnm, [-1_000_000, 1000, 123]);
    assert_eq!(k[2].flags, FLAG_BUTTON_1 | FLAG_BUTTON_2);
    assert_eq!(k[3].flags, FLAG_DEAD_MAN);
}

#[test]
fn every_error_kind_with_line_and_column() {
    assert_eq!(err(b"x 0 0 0 0 0 0"), (1, 1, EffortErrorKind::BadTime));
    assert_eq!(
        err(b"0 0 0 0 0 0 0\n  4000000001 0 0 0 0 0 0"),
        (2, 3, EffortErrorKind::TimeOutOfRange)
    );
    assert_eq!(
        err(b"5 0 0 0 0 0 0\n5 0 0 0 0 0 0"),
        (2, 1, EffortErrorKind::TimeNotIncreasing)
    );
    assert_eq!(
        err(b"# c\n0 0 0 1.2.3 0 0 0"),
        (2, 7, EffortErrorKind::BadNumber)
    );
    assert_eq!(err(b"0 0 0 - 0 0 0"), (1, 7, EffortErrorKind::BadNumber));
    assert_eq!(err(b"0 0 1e3 0 0 0 0"), (1, 5, EffortErrorKind::BadNumber));
    assert_eq!(
        err(b"0 0 0 0 0 0 1000.0005"),
        (1, 13, EffortErrorKind::ValueOutOfRange)
    );
    assert_eq!(err(b"0 0 0 0 0 0"), (1, 12, EffortErrorKind::MissingField));
    assert_eq!(
        err(b"0 0 0 0 0 0 0 1 0 0 7"),
        (1, 21, EffortErrorKind::TooManyFields)
    );
    assert_eq!(err(b"0 0 0 0 0 0 0 2"), (1, 15, EffortErrorKind::BadFlag));
    assert_eq!(err(b"# only\n\n"), (4, 1, EffortErrorKind::Empty));
    assert_eq!(err(b""), (2, 1, EffortErrorKind::Empty));
    let mut small = [EffortKeyframe::ZERO; 1];
    let e = parse_effort_sequence(b"0 0 0 0 0 0 0\n1 0 0 0 0 0 0\n", &mut small).unwrap_err();
    assert_eq!(
        (e.line, e.column, e.kind),
        (2, 1, EffortErrorKind::TooManyKeyframes)
    );
}

#[test]
fn player_interpolates_and_live_overrides() {
    let mut p = EffortPlayer::new();
    assert_eq!(p.sample(0), EffortSample::NONE);
    p.load_text(GOOD).unwrap();
    assert_eq!(p.len(), 4);
    let s = p.sample(250_000); // half way 0 → 500 ms
    assert_eq!(s.wrench.force.x, Fx::from_milli(1250));
    assert_eq!(s.wrench.force.z, Fx::from_milli(-625));
    assert!(s.dead_man);
    let s = p.sample(1_600_000);
    assert!(!s.dead_man);
    assert_eq!(s.buttons, 3);
    let s = p.sample(10_000_000);
    assert_eq!(s.wrench.force.x, Fx::ZERO);
    // Going back in time works too.
    let s = p.sample(500_000);
    assert_eq!(s.wrench.force.x, Fx::from_milli(2500));
    let live = EffortSample {
        wrench: Default::default(),
        dead_man: true,
        buttons: 1,
    };
    p.set_live(Some(live));
    assert_eq!(p.sample(250_000), live);
    p.set_live(None);
    assert_ne!(p.sample(250_000), live);
}

proptest! {
    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        let mut out = [EffortKeyframe::ZERO; 8];
        let _ = parse_effort_sequence(&bytes, &mut out);
        let mut p = EffortPlayer::new();
        if p.load_text(&bytes).is_ok() {
            for t in [0u64, 1, 999, 1_000_000, u64::MAX] {
                let _ = p.sample(t);
            }
        }
    }

    #[test]
    fn random_lines_never_panic(lines in proptest::collection::vec("[0-9 .+\\-#\t]{0,40}", 0..20)) {
        let text = lines.join("\n");
        let mut out = [EffortKeyframe::ZERO; 8];
        let _ = parse_effort_sequence(text.as_bytes(), &mut out);
    }

    #[test]
    fn numbers_round_trip(m in -1_000_000i32..=1_000_000) {
        let s = format!("{}{}.{:03}", if m < 0 { "-" } else { "" }, m.unsigned_abs() / 1000, m.unsigned_abs() % 1000);
        prop_assert_eq!(parse_milli(s.as_bytes()), Ok(m));
    }
}

#[test]
fn a_refused_sequence_keeps_the_loaded_one() {
    use hap_core::effort::EffortPlayer;
    let mut p = EffortPlayer::new();
    let good = b"0 1 0 0 0 0 0\n1000 2 0 0 0 0 0\n";
    assert_eq!(p.load_text(good), Ok(2));
    let before = p.sample(500_000);
    let bad = b"0 1 2 3\n";
    assert!(p.load_text(bad).is_err());
    assert_eq!(p.len(), 2, "the loaded sequence survives a refused load");
    assert_eq!(p.sample(500_000), before);
}

#[test]
fn effort_device_commands() {
    use hap_core::effort::{
        parse_effort_command, EffortCommand, EffortCommandError, EFFORT_CAPACITY,
    };
    use hap_core::fixed::Fx;
    assert_eq!(
        parse_effort_command(b"clear\n", EFFORT_CAPACITY),
        Ok(EffortCommand::Clear)
    );
    assert_eq!(
        parse_effort_command(b"live off", EFFORT_CAPACITY),
        Ok(EffortCommand::LiveOff)
    );
    match parse_effort_command(b"live 1.5 0 -2 0 0 0.25\n", EFFORT_CAPACITY) {
        Ok(EffortCommand::Live(s)) => {
            assert!(s.dead_man);
            assert_eq!(s.wrench.force.x, Fx::from_milli(1500));
            assert_eq!(s.wrench.force.z, Fx::from_milli(-2000));
            assert_eq!(s.wrench.torque.z, Fx::from_milli(250));
        }
        other => panic!("{other:?}"),
    }
    for bad in [
        &b"live 1 2 3 4 5"[..],
        b"live 1 2 3 4 5 6 7",
        b"live 1 2 x 4 5 6",
        b"live ",
    ] {
        assert_eq!(
            parse_effort_command(bad, EFFORT_CAPACITY),
            Err(EffortCommandError::BadLive),
            "{bad:?}"
        );
    }
    let seq = b"0 1 0 0 0 0 0\n1000 2 0 0 0 0 0\n";
    assert_eq!(
        parse_effort_command(seq, EFFORT_CAPACITY),
        Ok(EffortCommand::Sequence {
            text: seq,
            keyframes: 2
        })
    );
    match parse_effort_command(b"0 1 2 3\n", EFFORT_CAPACITY) {
        Err(EffortCommandError::Sequence(e)) => assert_eq!(e.line, 1),
        other => panic!("{other:?}"),
    }
}

#[test]
fn long_numbers_saturate_instead_of_overflowing() {
    // A 64 KiB field: the digit counter and the fraction saturate, the
    // value is judged on what it means.
    let mut frac = b"1.".to_vec();
    frac.extend(std::iter::repeat_n(b'9', 65_536));
    assert_eq!(parse_milli(&frac), Ok(2000), "1.999... rounds to 2.000");
    let mut neg = b"-0.".to_vec();
    neg.extend(std::iter::repeat_n(b'0', 65_536));
    neg.push(b'5');
    assert_eq!(parse_milli(&neg), Ok(0));
    let big = vec![b'9'; 65_536];
    assert_eq!(parse_milli(&big), Err(EffortErrorKind::ValueOutOfRange));
    let mut big_neg = b"-".to_vec();
    big_neg.extend(std::iter::repeat_n(b'9', 65_536));
    assert_eq!(parse_milli(&big_neg), Err(EffortErrorKind::ValueOutOfRange));
    assert_eq!(parse_milli(b"-1000"), Ok(-1_000_000));
    assert_eq!(
        parse_milli(b"-1000.0005"),
        Err(EffortErrorKind::ValueOutOfRange)
    );
}

#[test]
fn line_and_column_of_an_error_after_many_lines() {
    // 70 000 blank or comment lines, then a short line: the line number
    // counts them all, the column points past the last field.
    let mut t = Vec::new();
    for i in 0..70_000 {
        t.extend_from_slice(if i % 2 == 0 { b"\n" } else { b"# c\n" });
    }
    t.extend_from_slice(b"5 1 2 3 \t \r\n");
    assert_eq!(err(&t), (70_001, 8, EffortErrorKind::MissingField));
}
