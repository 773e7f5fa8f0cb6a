//! [`EmulationLayer`]: emulation as one layer of a [`LayerStack`](crate::layer::LayerStack).

use std::sync::Arc;
use std::time::Instant;

use super::settings::EmulatedSettings;

use crate::layer::{LayerContext, LayerError, LinkLayer, OpenBelow};
use crate::{FrameSink, Link};

use super::link::EmulatedLink;
use super::model::LinkModel;
use super::params::{EmulationError, ModelParams};
use super::positions::PositionTable;

/// Puts an [`EmulatedLink`] over a link: every frame sent goes through a [`LinkModel`] built
/// from `params` and `seed`. Received frames are not touched (the sender's model already
/// judged them), so the sink is not wrapped.
///
/// Under simulation ([`LayerContext::virtual_time`]) the layer leaves the link alone: the
/// simulator applies the same model itself, in virtual time.
#[derive(Clone)]
pub struct EmulationLayer {
    params: ModelParams,
    seed: u64,
    positions: PositionTable,
    epoch: Instant,
}

impl EmulationLayer {
    /// A layer applying the model of `params` (seeded with `seed`), with distances from
    /// `positions` and outage windows counted from `epoch`.
    pub fn new(params: ModelParams, seed: u64, positions: PositionTable, epoch: Instant) -> Self {
        EmulationLayer {
            params,
            seed,
            positions,
            epoch,
        }
    }

    /// The layer of an `emulated` transport from the fleet file: its profile and keys, its
    /// seed. Fails on an unknown profile or an invalid key, as [`LinkModel::from_settings`].
    pub fn from_settings(
        settings: &EmulatedSettings,
        positions: PositionTable,
        epoch: Instant,
    ) -> Result<Self, EmulationError> {
        // Build the model once so that every error shows now, not when a link is opened.
        let model = LinkModel::from_settings(settings)?;
        Ok(Self::new(
            model.params().clone(),
            model.seed(),
            positions,
            epoch,
        ))
    }

    /// The model's parameters.
    pub fn params(&self) -> &ModelParams {
        &self.params
    }
}

impl LinkLayer for EmulationLayer {
    fn name(&self) -> &str {
        "emulation"
    }

    fn wrap(
        &self,
        ctx: &LayerContext,
        sink: Arc<dyn FrameSink>,
        open: OpenBelow<'_>,
    ) -> Result<Arc<dyn Link>, LayerError> {
        // Received frames are not touched: the sender's model already judged them.
        let link = open(sink)?;
        if ctx.virtual_time {
            return Ok(link);
        }
        let failed = |e: EmulationError| LayerError::Wrap {
            layer: self.name().to_string(),
            source: Box::new(e),
        };
        let model = LinkModel::new(self.params.clone(), self.seed).map_err(failed)?;
        let link =
            EmulatedLink::with_epoch(link, ctx.local, model, self.positions.clone(), self.epoch)
                .map_err(failed)?;
        Ok(Arc::new(link))
    }
}
