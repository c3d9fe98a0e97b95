"""Learning from self-exploration: shard files, data collection and streams, the shadow self-model, the inverse CNN,
and the one trainer and checkpoint format they share."""
