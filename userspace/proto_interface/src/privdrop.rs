//! Least privilege: after it has read its key and set its scheduling
//! policy, the bridge runs as an unprivileged user whose group owns only the
//! kernel module's two FIFO devices (the launch script sets their group and
//! mode). With `keep_nice` (an RT priority was asked for) it keeps
//! CAP_SYS_NICE and nothing else; otherwise no capability at all. Also sets
//! `no_new_privs`.

use std::io::{Error, ErrorKind, Result};

/// A user and group to run as.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ids {
    pub uid: u32,
    pub gid: u32,
}

/// Capability number of CAP_SYS_NICE (linux/capability.h).
pub const CAP_SYS_NICE: u32 = 23;
const LINUX_CAPABILITY_VERSION_3: u32 = 0x2008_0522;

/// Parse `USER[:GROUP]`, names or numbers; names are looked up in
/// `passwd`/`group` text (the contents of /etc/passwd and /etc/group). A
/// user without `:GROUP` runs with its primary group.
pub fn resolve(spec: &str, passwd: &str, group: &str) -> Result<Ids> {
    let bad = |m: String| Error::new(ErrorKind::InvalidInput, m);
    let (user, grp) = match spec.split_once(':') {
        Some((u, g)) => (u, Some(g)),
        None => (spec, None),
    };
    let field = |text: &str, name: &str, idx: usize| -> Option<u32> {
        text.lines()
            .map(|l| l.split(':').collect::<Vec<_>>())
            .find(|f| f.first() == Some(&name))
            .and_then(|f| f.get(idx).and_then(|v| v.parse().ok()))
    };
    let (uid, primary) = match user.parse::<u32>() {
        Ok(n) => (n, None),
        Err(_) => (
            field(passwd, user, 2).ok_or_else(|| bad(format!("unknown user '{user}'")))?,
            field(passwd, user, 3),
        ),
    };
    let gid = match grp {
        Some(g) => match g.parse::<u32>() {
            Ok(n) => n,
            Err(_) => field(group, g, 2).ok_or_else(|| bad(format!("unknown group '{g}'")))?,
        },
        None => primary.ok_or_else(|| bad(format!("'{user}': give a group (USER:GROUP)")))?,
    };
    if uid == 0 || gid == 0 {
        return Err(bad("refusing to 'drop' to root".into()));
    }
    Ok(Ids { uid, gid })
}

fn check(rc: libc::c_int, what: &str) -> Result<()> {
    if rc == 0 {
        Ok(())
    } else {
        let e = Error::last_os_error();
        Err(Error::new(e.kind(), format!("{what}: {e}")))
    }
}

#[repr(C)]
struct CapHeader {
    version: u32,
    pid: libc::c_int,
}

#[repr(C)]
#[derive(Clone, Copy, Default)]
struct CapData {
    effective: u32,
    permitted: u32,
    inheritable: u32,
}

/// Become `ids` for good (real, effective and saved ids; no supplementary
/// groups), keeping CAP_SYS_NICE if `keep_nice`. Must run before any
/// thread is started (ids and capabilities are per thread on Linux; the
/// threads started later inherit them).
pub fn drop_to(ids: Ids, keep_nice: bool) -> Result<()> {
    // SAFETY: plain syscalls with integer arguments or valid pointers to
    // local, initialised structures that outlive each call.
    unsafe {
        check(
            libc::prctl(
                libc::PR_SET_KEEPCAPS,
                libc::c_ulong::from(keep_nice),
                0,
                0,
                0,
            ),
            "prctl(PR_SET_KEEPCAPS)",
        )?;
        check(libc::setgroups(0, std::ptr::null()), "setgroups")?;
        check(libc::setresgid(ids.gid, ids.gid, ids.gid), "setresgid")?;
        check(libc::setresuid(ids.uid, ids.uid, ids.uid), "setresuid")?;
        let keep = if keep_nice { 1u32 << CAP_SYS_NICE } else { 0 };
        let mut hdr = CapHeader {
            version: LINUX_CAPABILITY_VERSION_3,
            pid: 0,
        };
        let data = [
            CapData {
                effective: keep,
                permitted: keep,
                inheritable: 0,
            },
            CapData::default(),
        ];
        check(
            libc::syscall(libc::SYS_capset, &mut hdr as *mut CapHeader, data.as_ptr())
                as libc::c_int,
            "capset",
        )?;
        check(
            libc::prctl(libc::PR_SET_KEEPCAPS, 0, 0, 0, 0),
            "prctl(PR_SET_KEEPCAPS, 0)",
        )?;
        check(
            libc::prctl(libc::PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0),
            "prctl(PR_SET_NO_NEW_PRIVS)",
        )?;
        // The way back must be closed.
        if libc::setuid(0) == 0 {
            return Err(Error::other("setuid(0) still succeeds after the drop"));
        }
    }
    Ok(())
}

/// The effective capability set of this thread, from /proc (for logs/tests).
pub fn effective_caps() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/thread-self/status").ok()?;
    let l = s.lines().find(|l| l.starts_with("CapEff:"))?;
    u64::from_str_radix(l.trim_start_matches("CapEff:").trim(), 16).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    const PASSWD: &str = "root:x:0:0::/root:/bin/sh\nhapticctrl:x:990:990::/:/bin/false\n";
    const GROUP: &str = "root:x:0:\nhapticctrl:x:990:\nhapfifo:x:991:\n";

    #[test]
    fn resolves_names_numbers_and_refuses_root() {
        assert_eq!(
            resolve("hapticctrl", PASSWD, GROUP).unwrap(),
            Ids { uid: 990, gid: 990 }
        );
        assert_eq!(
            resolve("hapticctrl:hapfifo", PASSWD, GROUP).unwrap(),
            Ids { uid: 990, gid: 991 }
        );
        assert_eq!(
            resolve("1234:1235", "", "").unwrap(),
            Ids {
                uid: 1234,
                gid: 1235
            }
        );
        assert!(resolve("nobody-here", PASSWD, GROUP).is_err());
        assert!(resolve("1234", "", "").is_err(), "a number needs a group");
        assert!(resolve("root", PASSWD, GROUP).is_err());
        assert!(resolve("hapticctrl:root", PASSWD, GROUP).is_err());
    }

    /// Runs only as root (the e2e guest checks the running bridge too): in a
    /// child process, drop to 65534 keeping CAP_SYS_NICE, then check the ids,
    /// the capability set and that the way back is closed.
    #[test]
    fn drop_keeps_only_cap_sys_nice() {
        // SAFETY: getuid has no preconditions.
        if unsafe { libc::getuid() } != 0 {
            eprintln!("skipped: not root");
            return;
        }
        // SAFETY: fork in a test; the child only makes syscalls and exits.
        let pid = unsafe { libc::fork() };
        if pid == 0 {
            let ok = drop_to(
                Ids {
                    uid: 65534,
                    gid: 65534,
                },
                true,
            )
            .is_ok()
                && effective_caps() == Some(1 << CAP_SYS_NICE)
                // SAFETY: getters without preconditions.
                && unsafe { libc::geteuid() } == 65534
                && unsafe { libc::getegid() } == 65534;
            // SAFETY: _exit in the forked child.
            unsafe { libc::_exit(if ok { 0 } else { 1 }) };
        }
        assert!(pid > 0);
        let mut st = 0;
        // SAFETY: waiting for our own child with a valid out pointer.
        unsafe { libc::waitpid(pid, &mut st, 0) };
        assert!(
            libc::WIFEXITED(st) && libc::WEXITSTATUS(st) == 0,
            "status {st}"
        );
    }
}
