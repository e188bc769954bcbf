//! The deployment files say what they do: the Kubernetes manifest pins its image and bounds its
//! CPU (the worker count follows the cgroup's quota), and every `Documentation=` file of the
//! systemd unit is installed by the unit's own install steps and shipped in the image.

use std::path::Path;

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

fn read(p: &str) -> String {
    std::fs::read_to_string(Path::new(ROOT).join(p)).unwrap()
}

#[test]
fn kubernetes_pins_the_image_and_limits_cpu() {
    let k8s = read("deploy/kubernetes/gatewatch.yaml");
    let image = k8s
        .lines()
        .find_map(|l| l.trim().strip_prefix("image: "))
        .expect("an image");
    let tag = image.rsplit_once(':').map(|x| x.1).expect("a tag");
    assert!(tag != "latest" && !tag.is_empty(), "image {image}");
    assert!(k8s.contains("imagePullPolicy: IfNotPresent"));
    let limits = k8s
        .lines()
        .find_map(|l| l.trim().strip_prefix("limits: "))
        .expect("resource limits");
    assert!(
        limits.contains("cpu:") && limits.contains("memory:"),
        "{limits}"
    );
}

#[test]
fn systemd_documentation_is_installed() {
    let unit = read("deploy/systemd/gatewatch.service");
    let docs: Vec<&str> = unit
        .lines()
        .filter_map(|l| l.strip_prefix("Documentation="))
        .flat_map(|l| l.split_whitespace())
        .collect();
    assert!(!docs.is_empty());
    let install = unit
        .lines()
        .find(|l| l.contains("/usr/share/doc/gatewatch") && l.starts_with("#   install"))
        .expect("an install step for the documentation");
    let dockerfile = read("Dockerfile");
    for d in docs {
        let file = d
            .strip_prefix("file:///usr/share/doc/gatewatch/")
            .unwrap_or_else(|| panic!("{d}: not under /usr/share/doc/gatewatch"));
        let source = if file == "README.md" {
            file.to_string()
        } else {
            format!("docs/{file}")
        };
        assert!(
            Path::new(ROOT).join(&source).exists(),
            "{source} is missing"
        );
        let glob = if file == "README.md" {
            "README.md"
        } else {
            "docs/*.md"
        };
        assert!(
            install.contains(glob),
            "the install step does not install {source}"
        );
        assert!(
            dockerfile.contains(glob),
            "the image does not ship {source}"
        );
    }
}
