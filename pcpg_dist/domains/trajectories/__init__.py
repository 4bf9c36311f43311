"""The built-in ``trajectories`` domain: a user's own play logs (Parquet or Minari), optionally
rolled out in a Gymnasium env. See docs/bring-your-own-data.md."""
