//! The demo's 3D page in headless Chromium (Debian's `chromium`): the demo
//! runs against its in-process fake controller, Chromium loads the page and
//! dumps the DOM after a virtual-time budget, and the test reads the page's
//! own state (`window.demoState`, mirrored into `<pre id="state">`) to check
//! that the coupled sphere moves when the arm moves, and follows it.
//! Skipped, with a printed reason, when no chromium is installed.

use std::io::{BufRead, BufReader, Read};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

fn find_chromium() -> Option<PathBuf> {
    if let Ok(p) = std::env::var("CHROMIUM") {
        return Some(PathBuf::from(p));
    }
    let path = std::env::var_os("PATH")?;
    for d in std::env::split_paths(&path) {
        for name in ["chromium", "chromium-browser", "google-chrome"] {
            let p = d.join(name);
            if p.is_file() {
                return Some(p);
            }
        }
    }
    None
}

struct Demo(Child);
impl Drop for Demo {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// The number after `"key":` in the JSON text.
fn field(json: &str, key: &str) -> f64 {
    let pat = format!("\"{key}\":");
    let Some(i) = json.find(&pat) else {
        panic!("{key} missing in {json}");
    };
    let rest = &json[i + pat.len()..];
    let end = rest.find([',', '}', ']']).unwrap_or(rest.len());
    rest[..end]
        .trim()
        .parse()
        .unwrap_or_else(|_| panic!("{key}: not a number in {json}"))
}

#[test]
fn page_shows_the_coupled_sphere_following_the_arm() {
    let Some(chromium) = find_chromium() else {
        println!(
            "SKIPPED: chromium not installed (apt-get install -y --no-install-recommends chromium)"
        );
        return;
    };
    let mut child = Command::new(env!("CARGO_BIN_EXE_virtuose_demo"))
        .args([
            "--server",
            "fake",
            "--http",
            "127.0.0.1:0",
            "--duration",
            "40",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start the demo");
    let out = child.stdout.take().unwrap();
    let demo = Demo(child);
    let mut lines = BufReader::new(out).lines();
    let url = loop {
        let Some(Ok(l)) = lines.next() else {
            panic!("demo exited before printing its URL");
        };
        if let Some(u) = l.strip_prefix("UI: ") {
            break u.to_string();
        }
    };
    // Drain the rest of the demo's output in the background.
    std::thread::spawn(move || for _ in lines.by_ref() {});

    let profile = std::env::temp_dir().join(format!("demo_chromium_{}", std::process::id()));
    let mut chrome = Command::new(&chromium)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--no-first-run",
            "--virtual-time-budget=6000",
            "--dump-dom",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg(&url)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("start chromium");
    let mut dom = String::new();
    let mut so = chrome.stdout.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = so.read_to_string(&mut s);
        s
    });
    let t = Instant::now();
    loop {
        if chrome.try_wait().unwrap().is_some() {
            break;
        }
        if t.elapsed() > Duration::from_secs(90) {
            let _ = chrome.kill();
            let _ = chrome.wait();
            panic!("chromium did not finish within 90 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    dom.push_str(&reader.join().unwrap());
    let _ = std::fs::remove_dir_all(&profile);
    drop(demo);

    let start = dom
        .find("<pre id=\"state\">")
        .map(|i| i + "<pre id=\"state\">".len());
    let Some(start) = start else {
        panic!("no state element in the dumped DOM:\n{dom}");
    };
    let end = dom[start..]
        .find("</pre>")
        .map(|e| start + e)
        .unwrap_or(dom.len());
    let json = &dom[start..end];
    println!("window.demoState = {json}");
    let polls = field(json, "polls");
    let handle_range = field(json, "handleRange");
    let coupled_range = field(json, "coupledRange");
    let err_max = field(json, "couplingErrorMax");
    let frames = field(json, "frames");
    println!(
        "page: {polls} polls, {frames} frames drawn in {:.1} s; handle moved {handle_range:.4} m, coupled sphere {coupled_range:.4} m, max coupling error {err_max:.4} m",
        t.elapsed().as_secs_f64()
    );
    assert!(polls >= 10.0, "the page polled only {polls} times");
    assert!(frames >= 10.0);
    assert!(handle_range > 0.01, "the arm did not move on the page");
    assert!(
        coupled_range > 0.01,
        "the coupled sphere did not move with the arm"
    );
    assert!(
        err_max < 0.01,
        "the coupled sphere did not follow the handle (error {err_max} m)"
    );
    assert_eq!(field(json, "errors"), 0.0);
}
