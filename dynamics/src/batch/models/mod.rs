//! Lane implementations of the models, and the choice of one for a run.

mod dynamic;
mod expression;
mod fput;
mod henon_heiles;

use std::sync::Arc;

pub use dynamic::DynLanes;

use crate::model::{ExpressionModel, FputBeta, HenonHeiles, SeparableHamiltonian};

/// A model with its lane implementation, chosen once per run so the kernel is monomorphic
/// (inlined into the SIMD instantiations) for the models chaoscope ships.
#[derive(Clone)]
pub enum AnyLaneModel {
    HenonHeiles(HenonHeiles),
    Fput(FputBeta),
    /// A user-written potential: its compiled lane functions.
    Expression(ExpressionModel),
    /// Any other model: lane by lane through the scalar trait methods (correct, not fast).
    Other(DynLanes),
}

impl AnyLaneModel {
    /// The lane implementation of `model`, found by its type: the models chaoscope ships have
    /// their own, any other model goes lane by lane through its scalar methods.
    pub fn new(model: Arc<dyn SeparableHamiltonian>) -> Self {
        let any: &dyn std::any::Any = model.as_ref();
        if let Some(m) = any.downcast_ref::<ExpressionModel>() {
            Self::Expression(m.clone())
        } else if let Some(m) = any.downcast_ref::<FputBeta>() {
            Self::Fput(*m)
        } else if any.is::<HenonHeiles>() {
            Self::HenonHeiles(HenonHeiles)
        } else {
            Self::Other(DynLanes::new(model))
        }
    }
}

/// Calls `$body` with `$m` bound to the concrete lane model.
#[macro_export]
macro_rules! with_lane_model {
    ($any:expr, |$m:ident| $body:expr) => {
        match $any {
            $crate::batch::AnyLaneModel::HenonHeiles($m) => $body,
            $crate::batch::AnyLaneModel::Fput($m) => $body,
            $crate::batch::AnyLaneModel::Expression($m) => $body,
            $crate::batch::AnyLaneModel::Other($m) => $body,
        }
    };
}
