"""What a run leaves behind besides its step log: recordings and figures."""
