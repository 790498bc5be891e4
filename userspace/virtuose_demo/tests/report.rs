//! The web page links to the run's report: with `--results DIR --linger S`
//! the demo keeps serving after the run, `state.json` says `"report":true`
//! once DIR/plots/summary.html exists, and `/report/NAME` serves the files
//! of DIR/plots (plain names only).

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

struct Demo(Child);
impl Drop for Demo {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn get(addr: &str, path: &str) -> (String, Vec<u8>) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(s, "GET {path} HTTP/1.0\r\nHost: x\r\n\r\n").unwrap();
    let mut all = Vec::new();
    s.read_to_end(&mut all).unwrap();
    let split = all
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("a header");
    let head = String::from_utf8_lossy(&all[..split]).to_string();
    (head, all[split + 4..].to_vec())
}

#[test]
fn the_page_links_to_the_run_report_once_it_exists() {
    let dir = std::env::temp_dir().join(format!("demo_report_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut child = Command::new(env!("CARGO_BIN_EXE_virtuose_demo"))
        .args([
            "--server",
            "fake",
            "--http",
            "127.0.0.1:0",
            "--duration",
            "1",
        ])
        .arg("--results")
        .arg(&dir)
        .args(["--linger", "60"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("start the demo");
    let out = child.stdout.take().unwrap();
    let _demo = Demo(child);
    let mut lines = BufReader::new(out).lines();
    let url = loop {
        let Some(Ok(l)) = lines.next() else {
            panic!("demo exited before printing its URL");
        };
        if let Some(u) = l.strip_prefix("UI: ") {
            break u.to_string();
        }
    };
    std::thread::spawn(move || for _ in lines.by_ref() {});
    let addr = url
        .trim_start_matches("http://")
        .trim_end_matches('/')
        .to_string();

    // Wait for the end of the run: no report yet.
    let t = Instant::now();
    loop {
        let (_, body) = get(&addr, "/state.json?since=-1");
        let j = String::from_utf8_lossy(&body).to_string();
        if j.contains("\"done\":true") {
            assert!(j.contains("\"report\":false"), "{j}");
            break;
        }
        assert!(t.elapsed() < Duration::from_secs(60), "the run did not end");
        std::thread::sleep(Duration::from_millis(200));
    }
    let (head, _) = get(&addr, "/report/summary.html");
    assert!(head.starts_with("HTTP/1.0 404"), "{head}");

    // `hapctl analyze` writes the report: the page is told, the files served.
    std::fs::create_dir_all(dir.join("plots")).unwrap();
    std::fs::write(dir.join("plots/summary.html"), "<h1>report</h1>").unwrap();
    std::fs::write(dir.join("plots/forces.png"), b"\x89PNG....").unwrap();
    let (_, body) = get(&addr, "/state.json?since=-1");
    assert!(String::from_utf8_lossy(&body).contains("\"report\":true"));
    let (head, body) = get(&addr, "/report/summary.html");
    assert!(
        head.starts_with("HTTP/1.0 200") && head.contains("text/html"),
        "{head}"
    );
    assert_eq!(body, b"<h1>report</h1>");
    let (head, body) = get(&addr, "/report/forces.png");
    assert!(head.contains("image/png"), "{head}");
    assert_eq!(&body[1..4], b"PNG");
    // Nothing outside the report directory, nothing without a known type.
    for bad in [
        "/report/../summary.txt",
        "/report/..%2fsummary.txt",
        "/report/.hidden.html",
        "/report/plots/summary.html",
        "/report/summary",
    ] {
        let (head, _) = get(&addr, bad);
        assert!(head.starts_with("HTTP/1.0 404"), "{bad}: {head}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
