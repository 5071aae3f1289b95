"""Virtual dyno: test protocols, measured-data files and plots."""
