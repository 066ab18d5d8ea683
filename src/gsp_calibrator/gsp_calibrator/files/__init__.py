"""The files a run leaves and the platform's history of them: samples.csv, result/check files, the SQLite index (pure)."""
