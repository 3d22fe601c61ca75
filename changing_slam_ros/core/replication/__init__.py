"""Map replication between the split nodes: map updates, replicas and what was in flight across a merge."""
