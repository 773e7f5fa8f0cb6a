//! The TLS client configuration: the broker's CA (or the operating system's roots) and, for
//! brokers that require one, this system's certificate and key. rustls with the ring provider.

use std::path::Path;
use std::sync::Arc;

use rumqttc::tokio_rustls::rustls;
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};

use crate::settings::MqttSettings;

fn certificates(path: &Path, what: &str) -> Result<Vec<CertificateDer<'static>>, String> {
    let certs: Vec<CertificateDer<'static>> = CertificateDer::pem_file_iter(path)
        .and_then(|it| it.collect::<Result<_, _>>())
        .map_err(|e| format!("cannot read {what} `{}`: {e}", path.display()))?;
    if certs.is_empty() {
        return Err(format!(
            "{what} `{}` holds no PEM certificate",
            path.display()
        ));
    }
    Ok(certs)
}

/// The rustls client configuration for `s`.
pub(crate) fn client_config(s: &MqttSettings) -> Result<Arc<rustls::ClientConfig>, String> {
    let mut roots = rustls::RootCertStore::empty();
    match &s.ca_file {
        Some(ca) => {
            for cert in certificates(ca, "`ca_file`")? {
                roots
                    .add(cert)
                    .map_err(|e| format!("`ca_file` `{}`: {e}", ca.display()))?;
            }
        }
        None => {
            let found = rustls_native_roots();
            if found.is_empty() {
                return Err("no `ca_file` given and the operating system has no CA certificates: set `ca_file`".into());
            }
            roots.add_parsable_certificates(found);
        }
    }
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let builder = rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(|e| format!("TLS: {e}"))?
        .with_root_certificates(roots);
    let config = match (&s.client_cert_file, &s.client_key_file) {
        (Some(cert), Some(key)) => {
            let chain = certificates(cert, "`client_cert_file`")?;
            let key = PrivateKeyDer::from_pem_file(key)
                .map_err(|e| format!("cannot read `client_key_file` `{}`: {e}", key.display()))?;
            builder
                .with_client_auth_cert(chain, key)
                .map_err(|e| format!("the client certificate and key do not fit: {e}"))?
        }
        _ => builder.with_no_client_auth(),
    };
    Ok(Arc::new(config))
}

/// The operating system's CA certificates (Debian's `/etc/ssl/certs/ca-certificates.crt`).
fn rustls_native_roots() -> Vec<CertificateDer<'static>> {
    let bundle = Path::new("/etc/ssl/certs/ca-certificates.crt");
    certificates(bundle, "the system CA bundle").unwrap_or_default()
}
