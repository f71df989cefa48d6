% orbit_worker: autotune's worker for the planar orbit-determination example.
%
% autotune starts this script once per worker (orbit.toml, [external] command):
%   octave --no-gui --quiet --norc --no-window-system orbit_worker.m
% and asks it for the EKF's records at parameter values theta over stdin/stdout
% (docs/external.md). Only protocol lines go to stdout; diagnostics go to stderr.
more off;
here = fileparts(mfilename('fullpath'));
if isempty(here)
  here = pwd;
end
addpath(here);
autotune_serve(@orbit_simulate);
