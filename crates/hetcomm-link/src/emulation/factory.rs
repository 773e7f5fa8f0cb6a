//! The `emulated` transport factory: a radio model ([`EmulationLayer`]) as the top layer of a
//! link that is either another transport of the fleet (`over`) or a private in-process hub.

use std::sync::Arc;

use hetcomm_config::{KindSpec, TransportDef, TransportKind};

use crate::layer::LinkLayer;
use crate::registry::{OpenFailure, OpenHost, OpenRequest, Opened, TransportFactory};

use super::settings::EmulatedSpec;
use super::{EmulatedSettings, EmulationLayer, LinkModel};

/// Opens `emulated` transports: the link under the model is the `over` transport's (opened by
/// the program, with its own layers) or a hub of its own; the model is the kind's
/// [`TransportFactory::layer`].
pub struct EmulatedFactory;

fn settings(t: &TransportDef) -> Result<&EmulatedSettings, OpenFailure> {
    t.settings.registered().ok_or_else(|| {
        format!(
            "transport `{}` has no emulated settings (it was not loaded with this program's kinds)",
            t.name
        )
        .into()
    })
}

impl TransportFactory for EmulatedFactory {
    fn kind(&self) -> TransportKind {
        TransportKind::Emulated
    }

    fn spec(self: Arc<Self>) -> Option<Arc<dyn KindSpec>> {
        Some(Arc::new(EmulatedSpec))
    }

    fn open(&self, request: OpenRequest<'_>) -> Result<Opened, OpenFailure> {
        let t = request.transport;
        match &t.over {
            Some(over) => {
                let index = request
                    .fleet
                    .transports
                    .iter()
                    .position(|o| &o.name == over)
                    .ok_or_else(|| format!("wrapped transport `{over}` not found"))?;
                let inner = request.host.open_transport(index, request.sink)?;
                let under = inner.local_address.as_deref().unwrap_or("in-process");
                Ok(Opened {
                    local_address: Some(format!("emulated over {under}")),
                    link: inner.link,
                })
            }
            None => {
                let hub = request.host.hub(&format!("emulated:{}", t.name));
                Ok(Opened {
                    link: Arc::new(hub.open(request.local, request.sink)),
                    local_address: None,
                })
            }
        }
    }

    /// Its own link is a private in-process hub; over another transport, that one's
    /// answer counts (the registry follows [`TransportDef::over`]).
    fn leaves_process(&self) -> bool {
        false
    }

    fn sim_model(
        &self,
        transport: &TransportDef,
        seed_mix: u64,
    ) -> Result<Option<LinkModel>, OpenFailure> {
        let mut settings = settings(transport)?.clone();
        settings.seed ^= seed_mix;
        Ok(Some(LinkModel::from_settings(&settings)?))
    }

    fn layer(
        &self,
        transport: &TransportDef,
        host: &dyn OpenHost,
    ) -> Result<Option<Arc<dyn LinkLayer>>, OpenFailure> {
        let layer =
            EmulationLayer::from_settings(settings(transport)?, host.positions(), host.epoch())?;
        Ok(Some(Arc::new(layer)))
    }
}
