"""Neural-network approximation of an MPC law: features, dataset, training, export (Study B)."""
