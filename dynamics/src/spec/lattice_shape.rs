//! `[model] lattice` and `boundary` of the Hamiltonians written as expressions: a chain of `n`
//! sites (`q[i]`) or an `n x n` square (`q[i, j]`), and what each axis sees beyond its ends.

use chaoscope_expr::lower::{Boundary, Shape};
use chaoscope_schemas::config::BoundaryConfig;

use super::SpecError;

/// The sites of a lattice model: their shape, the boundary along the chain (or the rows'
/// index `i` of a square), and how many there are.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Sites {
    pub shape: Shape,
    pub boundary: Boundary,
    pub count: usize,
}

/// `lattice` and `boundary` for a model whose `n` is `n` (a chain's length, a square's side).
pub(crate) fn sites(
    lattice: Option<&str>,
    boundary: Option<&BoundaryConfig>,
    n: usize,
) -> Result<Sites, SpecError> {
    let named =
        |name: &str| Boundary::from_name(name).map_err(|e| SpecError::new("model.boundary", e));
    let square = match lattice.unwrap_or("chain") {
        "chain" => false,
        "square" => true,
        other => {
            return Err(SpecError::new(
                "model.lattice",
                format!("'{other}' is not chain or square"),
            ));
        }
    };
    let (along_i, along_j) = match boundary {
        None => (Boundary::Fixed, Boundary::Fixed),
        Some(BoundaryConfig::Every(b)) => (named(b)?, named(b)?),
        Some(BoundaryConfig::PerAxis(axes)) if !square => {
            return Err(SpecError::new(
                "model.boundary",
                format!(
                    "one condition per axis ({} given) is for lattice = \"square\"; a chain has \
                     one: boundary = \"fixed\", \"periodic\" or \"free\"",
                    axes.len()
                ),
            ));
        }
        Some(BoundaryConfig::PerAxis(axes)) => match axes.as_slice() {
            [i, j] => (named(i)?, named(j)?),
            _ => {
                return Err(SpecError::new(
                    "model.boundary",
                    format!(
                        "a square lattice has two axes: give [along i, along j], e.g. \
                         [\"fixed\", \"periodic\"] (got {} entries)",
                        axes.len()
                    ),
                ));
            }
        },
    };
    if !square {
        return Ok(Sites {
            shape: Shape::Chain,
            boundary: along_i,
            count: n,
        });
    }
    let shape = Shape::Square { columns: along_j };
    let count = shape.sites(n).ok_or_else(|| {
        SpecError::new(
            "model.n",
            format!("a square of side {n} has more sites than can be counted"),
        )
    })?;
    Ok(Sites {
        shape,
        boundary: along_i,
        count,
    })
}

/// The sites (from 0) of `[orbit] excite.sites = l` or `[first, last]`: the site `l` or the
/// block on a chain; on a square of side `side` the site `(l, l)` or the square `[first, last]
/// x [first, last]` of rows and columns, numbered row by row.
pub(crate) fn excited_sites(
    (first, last): (usize, usize),
    chain: usize,
    side: Option<usize>,
) -> Result<Vec<usize>, SpecError> {
    let (extent, what) = match side {
        None => (chain, "sites"),
        Some(side) => (side, "rows and columns of the square"),
    };
    if first == 0 || first > last || last > extent {
        return Err(SpecError::new(
            "orbit.excite.sites",
            format!(
                "must be a site or a block [first, last] with 1 <= first <= last <= {extent} (the \
                 lattice has {extent} {what}), got {}",
                if first == last {
                    first.to_string()
                } else {
                    format!("[{first}, {last}]")
                }
            ),
        ));
    }
    Ok(match side {
        None => (first - 1..last).collect(),
        Some(side) => (first - 1..last)
            .flat_map(|i| (first - 1..last).map(move |j| i * side + j))
            .collect(),
    })
}
