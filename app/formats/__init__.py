"""Every file format rvis reads or writes: CSV measurement and target files, parameters
files, FANUC programs, reports, sweep folders, the wire trace."""
