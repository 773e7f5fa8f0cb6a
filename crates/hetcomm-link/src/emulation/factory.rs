//! The `emulated` transport factory: a radio model ([`EmulationLayer`]) as the top layer of a
//! link that is either another transport of the fleet (`over`) or a private in-process hub.

use std::sync::Arc;

use hetcomm_config::model::EmulatedSettings;
use hetcomm_config::{TransportDef, TransportKind, TransportSettings};

use crate::layer::LinkLayer;
use crate::registry::{OpenFailure, OpenHost, OpenRequest, Opened, TransportFactory};

use super::{EmulationLayer, LinkModel};

/// Opens `emulated` transports: the link under the model is the `over` transport's (opened by
/// the program, with its own layers) or a hub of its own; the model is the kind's
/// [`TransportFactory::layer`].
pub struct EmulatedFactory;

fn settings(t: &TransportDef) -> Result<&EmulatedSettings, OpenFailure> {
    match &t.settings {
        TransportSettings::Emulated(s) => Ok(s),
        other => Err(format!("expected emulated settings, found {other:?}").into()),
    }
}

impl TransportFactory for EmulatedFactory {
    fn kind(&self) -> TransportKind {
        TransportKind::Emulated
    }

    fn open(&self, request: OpenRequest<'_>) -> Result<Opened, OpenFailure> {
        let t = request.transport;
        match &settings(t)?.over {
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
    /// answer counts (the registry follows [`TransportFactory::over`]).
    fn leaves_process(&self) -> bool {
        false
    }

    fn over<'t>(&self, transport: &'t TransportDef) -> Option<&'t str> {
        match &transport.settings {
            TransportSettings::Emulated(s) => s.over.as_deref(),
            _ => None,
        }
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
