//! Data loader, training, evaluation, inference and experiments.
