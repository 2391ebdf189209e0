//! Checks that a controller's inputs are finite before it uses them, so that no controller ever
//! turns a NaN or infinity from upstream into a NaN command.

/// A controller input that is NaN or infinite. The caller should send a safe (stopping) command.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("non-finite controller input: {field}")]
pub struct NonFiniteInput {
    /// The input field at fault, e.g. `target.position`.
    pub field: &'static str,
}

/// Returns an error naming `field` if any of `values` is NaN or infinite.
pub fn ensure_finite<'a>(
    field: &'static str,
    values: impl IntoIterator<Item = &'a f64>,
) -> Result<(), NonFiniteInput> {
    if values.into_iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(NonFiniteInput { field })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_the_field_of_a_non_finite_value() {
        assert_eq!(ensure_finite("base.x", &[1.0, 2.0]), Ok(()));
        assert_eq!(
            ensure_finite("base.x", &[1.0, f64::NAN]),
            Err(NonFiniteInput { field: "base.x" })
        );
        assert!(ensure_finite("t", &[f64::NEG_INFINITY]).is_err());
    }
}
