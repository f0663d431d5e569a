"""The dataset format: files, splits, statistics, and the corpus build that writes them."""
