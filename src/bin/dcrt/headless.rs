//! Quiet GPU start-up on machines without a display.
//!
//! wgpu enables every window-system instance extension the Vulkan loader offers (it has no option
//! to leave them out), and Mesa's implicit `VK_LAYER_MESA_device_select` layer, seeing
//! `VK_KHR_wayland_surface` enabled, connects to Wayland in `vkEnumeratePhysicalDevices` to find
//! the display's GPU. Without `XDG_RUNTIME_DIR` libwayland then prints `error: XDG_RUNTIME_DIR is
//! invalid or not set in the environment.` once per call, twice a run: headless runs looked like
//! failures. The layer only reorders devices for a display, and dcrt ranks adapters itself, so
//! where there can be no Wayland display the process runs again with the layer's documented
//! switch, `NODEVICE_SELECT=1`, set (environment variables are read when the loader starts;
//! setting one in a running process is unsafe in Rust, running it again is not).

use std::ffi::OsString;

/// The variable the layer's manifest names as its off switch.
const SWITCH: &str = "NODEVICE_SELECT";

/// Whether libwayland would fail to find a display and complain: it needs `WAYLAND_SOCKET`, an
/// absolute `WAYLAND_DISPLAY`, or an absolute `XDG_RUNTIME_DIR`.
fn no_wayland(var: impl Fn(&str) -> Option<OsString>) -> bool {
    let absolute = |name: &str| var(name).is_some_and(|v| v.to_string_lossy().starts_with('/'));
    var("WAYLAND_SOCKET").is_none() && !absolute("WAYLAND_DISPLAY") && !absolute("XDG_RUNTIME_DIR")
}

/// Whether this process should run again with the layer switched off: no Wayland display is
/// possible, the switch is not set yet, and the user has not asked the layer to pick a device.
fn should_rerun(var: impl Fn(&str) -> Option<OsString>) -> bool {
    cfg!(target_os = "linux")
        && var(SWITCH).is_none()
        && var("MESA_VK_DEVICE_SELECT").is_none()
        && var("DRI_PRIME").is_none()
        && no_wayland(&var)
}

/// Runs this program again, same arguments, with the layer switched off, when that is what keeps
/// a headless run quiet. Returns only when there is nothing to do or the exec failed (the run
/// then goes on, noisier but correct).
pub fn rerun_quietly() {
    if !should_rerun(|k| std::env::var_os(k)) {
        return;
    }
    let Ok(exe) = std::env::current_exe() else {
        return;
    };
    use std::os::unix::process::CommandExt;
    let args: Vec<OsString> = std::env::args_os().skip(1).collect();
    let err = std::process::Command::new(exe)
        .args(args)
        .env(SWITCH, "1")
        .exec();
    log::debug!("could not run again without the device-select layer: {err}");
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env(pairs: &[(&str, &str)]) -> impl Fn(&str) -> Option<OsString> {
        let pairs: Vec<(String, OsString)> = pairs
            .iter()
            .map(|(k, v)| (k.to_string(), OsString::from(v)))
            .collect();
        move |k| pairs.iter().find(|(n, _)| n == k).map(|(_, v)| v.clone())
    }

    #[test]
    fn reruns_only_where_wayland_would_complain() {
        assert!(should_rerun(env(&[])));
        assert!(should_rerun(env(&[("XDG_RUNTIME_DIR", "relative")])));
        assert!(!should_rerun(env(&[("XDG_RUNTIME_DIR", "/run/user/1000")])));
        assert!(!should_rerun(env(&[("WAYLAND_DISPLAY", "/tmp/wl-0")])));
        assert!(!should_rerun(env(&[("WAYLAND_SOCKET", "5")])));
        assert!(!should_rerun(env(&[("NODEVICE_SELECT", "1")])));
        assert!(!should_rerun(env(&[(
            "MESA_VK_DEVICE_SELECT",
            "10de:2684"
        )])));
        assert!(!should_rerun(env(&[("DRI_PRIME", "1")])));
    }
}
