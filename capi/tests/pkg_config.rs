//! `glint.pc.in`, installed as the README says (`@PREFIX@` replaced), gives pkg-config the flags
//! a controller project needs: the include directory, `-lglint`, and for static linking the
//! system libraries a Rust static library needs (the same list the e2e test links the C++
//! example with).

use std::path::Path;
use std::process::Command;

#[test]
fn installed_pc_file_gives_include_and_link_flags() {
    let prefix = std::env::temp_dir().join(format!("glint-capi-pc-{}", std::process::id()));
    let pc_dir = prefix.join("lib/pkgconfig");
    std::fs::create_dir_all(&pc_dir).unwrap();
    let template =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("glint.pc.in")).unwrap();
    let prefix_str = prefix.to_str().unwrap();
    std::fs::write(
        pc_dir.join("glint.pc"),
        template.replace("@PREFIX@", prefix_str),
    )
    .unwrap();

    let flags = |args: &[&str]| {
        let out = Command::new("pkg-config")
            .env("PKG_CONFIG_PATH", &pc_dir)
            .args(args)
            .arg("glint")
            .output()
            .expect("pkg-config is installed");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout).unwrap()
    };
    let shared = flags(&["--cflags", "--libs"]);
    assert!(
        shared.contains(&format!("-I{prefix_str}/include")),
        "{shared}"
    );
    assert!(shared.contains(&format!("-L{prefix_str}/lib")), "{shared}");
    assert!(
        shared.contains("-lglint") && !shared.contains("-lpthread"),
        "{shared}"
    );
    let static_libs = flags(&["--static", "--libs"]);
    for lib in ["-lglint", "-lpthread", "-ldl", "-lm", "-lrt", "-lgcc_s"] {
        assert!(static_libs.contains(lib), "{lib} missing: {static_libs}");
    }
    assert_eq!(flags(&["--modversion"]).trim(), env!("CARGO_PKG_VERSION"));
    std::fs::remove_dir_all(prefix).unwrap();
}
