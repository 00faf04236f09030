//! A user-written potential over lanes: the compiled lane functions take the rows of the
//! structure of arrays as they are (`[[f64; L]]` flattened is row-major with stride `L`, the
//! layout the compiler's lane functions read), so all lanes go through native code in one call.

use crate::batch::lanes::LaneModel;
use crate::model::ExpressionModel;

impl LaneModel for ExpressionModel {
    #[inline(always)]
    fn gradient_lanes<const L: usize>(&self, q: &[[f64; L]], out: &mut [[f64; L]]) {
        self.gradient_soa(q.as_flattened(), out.as_flattened_mut(), L)
    }

    #[inline(always)]
    fn hessian_vector_lanes<const L: usize>(
        &self,
        q: &[f64],
        v: &[[f64; L]],
        out: &mut [[f64; L]],
    ) {
        self.hessian_vector_soa(q, v.as_flattened(), out.as_flattened_mut(), L)
    }
}
