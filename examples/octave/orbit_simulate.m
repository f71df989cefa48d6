function rec = orbit_simulate(theta, seed, runs, steps)
% ORBIT_SIMULATE  Planar low-Earth-orbit determination: truth Monte Carlo and an EKF.
%
%   rec = orbit_simulate(theta, seed, runs, steps) simulates runs [a, b) of the
%   experiment with base seed `seed` and returns the EKF's records in the layout of
%   autotune_serve: e, P and, per ground station gsK, nu_gsK and S_gsK.
%
%   theta.q_accel  PSD of the random acceleration the filter assumes, km^2/s^3
%   theta.r_range  range noise variance the filter assumes, km^2
%   theta.r_rate   range-rate noise variance the filter assumes, (km/s)^2
%
%   Truth. State [x, y, vx, vy] (km, km/s) in an Earth-centred inertial plane. Two-body
%   gravity integrated with ode45 between measurement times t_k = k dt, plus at every
%   step the integrated effect of a white random acceleration of PSD q (per axis) over
%   dt: w_k ~ N(0, q Qd), Qd = [dt^3/3 I, dt^2/2 I; dt^2/2 I, dt I]. Ground stations on
%   the rotating Earth measure range and range rate (station to satellite) when the
%   satellite is above their horizon (elevation > 0); otherwise that station has no
%   measurement at t_k (NaN), so the measurement dimension changes along the pass.
%
%   Filter. An EKF with the same dynamics: the mean and the state transition matrix
%   propagated together by RK4, P = Phi P Phi' + q_accel Qd, then one sequential update
%   per visible station with R = diag(r_range, r_rate) (Joseph form). All runs are
%   filtered together, vectorised over runs with element-wise arithmetic only, so each
%   run's numbers do not depend on which other runs share the request.
%
%   Seed contract: run i's initial error, process noise and measurement noise are drawn
%   after autotune_rng(seed, i), in a fixed order, whatever theta and the range asked
%   for. The truth does not depend on theta: it is cached per (seed, i, steps), so
%   ode45 runs once per run and not once per candidate of a tune.

  c = orbit_constants();
  for name = {'q_accel', 'r_range', 'r_rate'}
    if ~isfield(theta, name{1})
      error('orbit_simulate: theta has no %s (the parameters are q_accel, r_range, r_rate)', name{1});
    end
  end
  a = runs(1);
  b = runs(2);
  nr = b - a;
  T = steps;
  ns = size(c.stations, 1);

  % Truth and measurements of every run (cached).
  X = zeros(nr, T + 1, 4);           % truth at t_0 .. t_T
  Z = NaN(nr, T, 2, ns);             % measurements, NaN where not visible
  for r = 1:nr
    tr = orbit_truth(c, seed, a + r - 1, T);
    X(r, :, :) = reshape(tr.X, [1, T + 1, 4]);
    Z(r, :, :, :) = reshape(tr.Z, [1, T, 2, ns]);
  end

  q = theta.q_accel;
  R = [theta.r_range, theta.r_rate];
  Qk = reshape(q * c.Qd, [1, 4, 4]);

  xh = repmat(c.x0', nr, 1);                            % nr x 4
  P = repmat(reshape(c.P0, [1, 4, 4]), [nr, 1, 1]);     % nr x 4 x 4
  rec.e = zeros(nr, T, 4);
  rec.P = zeros(nr, T, 4, 4);
  for s = 1:ns
    rec.(sprintf('nu_gs%d', s)) = NaN(nr, T, 2);
    rec.(sprintf('S_gs%d', s)) = NaN(nr, T, 2, 2);
  end
  diverged = zeros(nr, 1);

  for k = 1:T
    % Prediction.
    [xh, Phi] = rk4_stm(xh, c.dt, c.substeps, c.mu);
    P = bmul(bmul(Phi, P), btrans(Phi)) + Qk;
    t = k * c.dt;
    % One update per station that sees the satellite.
    for s = 1:ns
      z = reshape(Z(:, k, :, s), [nr, 2]);
      idx = find(~isnan(z(:, 1)));
      if isempty(idx)
        continue;
      end
      [rs, vs] = station_state(c, s, t);
      [zh, H] = measure(xh(idx, :), rs, vs);
      Pi = P(idx, :, :);
      PHt = bmul(Pi, btrans(H));                          % m x 4 x 2
      S = bmul(H, PHt);
      S(:, 1, 1) = S(:, 1, 1) + R(1);
      S(:, 2, 2) = S(:, 2, 2) + R(2);
      S(:, 1, 2) = 0.5 * (S(:, 1, 2) + S(:, 2, 1));
      S(:, 2, 1) = S(:, 1, 2);
      nu = z(idx, :) - zh;
      dS = S(:, 1, 1) .* S(:, 2, 2) - S(:, 1, 2) .* S(:, 2, 1);
      Si = cat(3, cat(2, S(:, 2, 2), -S(:, 2, 1)), cat(2, -S(:, 1, 2), S(:, 1, 1))) ./ dS;
      K = bmul(PHt, Si);                                  % m x 4 x 2
      xh(idx, :) = xh(idx, :) + sum(K .* reshape(nu, [numel(idx), 1, 2]), 3);
      IKH = reshape(eye(4), [1, 4, 4]) - bmul(K, H);
      KR = K .* reshape(R, [1, 1, 2]);
      Pi = bmul(bmul(IKH, Pi), btrans(IKH)) + bmul(KR, btrans(K));
      P(idx, :, :) = 0.5 * (Pi + btrans(Pi));
      rec.(sprintf('nu_gs%d', s))(idx, k, :) = reshape(nu, [numel(idx), 1, 2]);
      rec.(sprintf('S_gs%d', s))(idx, k, :, :) = reshape(S, [numel(idx), 1, 2, 2]);
    end
    rec.e(:, k, :) = reshape(reshape(X(:, k + 1, :), [nr, 4]) - xh, [nr, 1, 4]);
    rec.P(:, k, :, :) = reshape(P, [nr, 1, 4, 4]);
    % A filter whose covariance stopped being a covariance has broken down.
    d = [P(:, 1, 1), P(:, 2, 2), P(:, 3, 3), P(:, 4, 4)];
    bad = any(~isfinite(reshape(P, nr, 16)), 2) | any(d <= 0, 2) | any(~isfinite(xh), 2);
    diverged(bad & diverged == 0) = k;
  end
  rec.diverged = diverged;
end

function c = orbit_constants()
  % The experiment's fixed settings. The truth's noise levels are repeated, for the
  % report, as [external] truth in orbit.toml.
  c.mu = 398600.4418;                % km^3/s^2
  c.RE = 6378.137;                   % km
  c.omega = 7.2921159e-5;            % rad/s, Earth rotation
  c.dt = 30;                         % s between measurements
  c.substeps = 3;                    % RK4 steps per dt in the filter
  c.q_true = 1e-10;                  % km^2/s^3
  c.r_range_true = 1e-4;             % km^2 (10 m)
  c.r_rate_true = 1e-8;              % (km/s)^2 (10 cm/s)
  % Stations: longitude at t = 0 (deg, from the satellite's starting direction).
  c.stations = [10; 40; 70];
  % Nominal initial state: circular orbit 400 km up, prograde (same sense as the Earth).
  r0 = c.RE + 400;
  c.x0 = [r0; 0; 0; sqrt(c.mu / r0)];
  c.P0 = diag([0.1^2, 0.1^2, 1e-4^2, 1e-4^2]);   % 100 m, 0.1 m/s per axis
  dt = c.dt;
  c.Qd = [dt^3/3 * eye(2), dt^2/2 * eye(2); dt^2/2 * eye(2), dt * eye(2)];
  % Octave's ode45 caps its step at a tenth of the interval unless told otherwise: with
  % MaxStep = dt it takes 3 or 4 steps per interval (position error ~1e-10 km).
  c.ode = odeset('RelTol', 1e-10, 'AbsTol', 1e-10, 'MaxStep', dt, 'InitialStep', dt / 3);
  c.block = 16;                      % runs per ode45 integration (see orbit_truth)
end

function tr = orbit_truth(c, seed, i, T)
  % Truth trajectory and measurements of run i, cached: they depend on (seed, i, T) only.
  %
  % An ode45 call costs a few ms in Octave (option parsing) before any integration, so
  % the runs are integrated in fixed blocks of c.block runs (block j holds runs
  % j*B .. j*B+B-1), stacked into one state: a block is always the same runs with the same
  % noise, so run i's truth is the same whichever range a request asks for (it may
  % compute a few runs more than asked, for later requests).
  persistent cache
  if isempty(cache)
    cache = containers.Map();
  end
  seed = uint64(seed);
  prefix = sprintf('%d:%d:%d:', double(bitshift(seed, -32)), ...
                   double(bitand(seed, uint64(4294967295))), T);
  key = sprintf('%s%d', prefix, i);
  if isKey(cache, key)
    tr = cache(key);
    return;
  end
  if cache.Count > 50000
    cache = containers.Map();              % a long tune over many seeds: start afresh
  end
  B = c.block;
  ns = size(c.stations, 1);
  members = floor(i / B) * B + (0:B-1);
  % Each run's random numbers, drawn from (seed, run) alone in a fixed order: the
  % initial error, then per step the process noise (4) and the measurement noise of
  % every station (2 each, drawn whether or not the station sees the satellite).
  L0 = chol(c.P0, 'lower');
  Lq = chol(c.q_true * c.Qd, 'lower');
  sr = sqrt([c.r_range_true; c.r_rate_true]);
  x = zeros(4, B);
  W = zeros(4 + 2 * ns, T, B);
  for j = 1:B
    autotune_rng(seed, members(j));
    x(:, j) = c.x0 + L0 * randn(4, 1);
    W(:, :, j) = randn(4 + 2 * ns, T);
  end
  X = zeros(T + 1, 4, B);
  Z = NaN(T, 2, ns, B);
  X(1, :, :) = reshape(x, [1, 4, B]);
  f = @(t, y) twobody(y, c.mu);
  for k = 1:T
    [~, y] = ode45(f, [(k - 1) * c.dt, k * c.dt], x(:), c.ode);
    x = reshape(y(end, :), [4, B]) + Lq * reshape(W(1:4, k, :), [4, B]);
    X(k + 1, :, :) = reshape(x, [1, 4, B]);
    t = k * c.dt;
    for s = 1:ns
      [rs, vs] = station_state(c, s, t);
      seen = find((x(1, :) - rs(1)) * rs(1) + (x(2, :) - rs(2)) * rs(2) > 0);   % elevation > 0
      if ~isempty(seen)
        zh = measure(x(:, seen)', rs, vs);
        v = reshape(W(4 + 2 * s - 1:4 + 2 * s, k, seen), [2, numel(seen)]);
        Z(k, :, s, seen) = reshape((zh + (sr .* v)')', [1, 2, 1, numel(seen)]);
      end
    end
  end
  for j = 1:B
    one.X = X(:, :, j);
    one.Z = Z(:, :, :, j);
    cache(sprintf('%s%d', prefix, members(j))) = one;
  end
  tr = cache(key);
end

function dy = twobody(y, mu)
  % Two-body gravity for a stack of states [x; y; vx; vy; x; y; ...].
  Y = reshape(y, 4, []);
  r3 = (Y(1, :).^2 + Y(2, :).^2).^1.5;
  dy = reshape([Y(3, :); Y(4, :); -mu * Y(1, :) ./ r3; -mu * Y(2, :) ./ r3], [], 1);
end

function [rs, vs] = station_state(c, s, t)
  % Station s's inertial position and velocity at time t (1 x 2 each).
  th = c.stations(s) * pi / 180 + c.omega * t;
  rs = c.RE * [cos(th), sin(th)];
  vs = c.omega * c.RE * [-sin(th), cos(th)];
end

function [zh, H] = measure(x, rs, vs)
  % Range and range rate from a station for each row of x (m x 4), with the Jacobian
  % H (m x 2 x 4).
  d = x(:, 1:2) - rs;
  dv = x(:, 3:4) - vs;
  rho = sqrt(d(:, 1).^2 + d(:, 2).^2);
  u = d ./ rho;
  rdot = u(:, 1) .* dv(:, 1) + u(:, 2) .* dv(:, 2);
  zh = [rho, rdot];
  if nargout > 1
    m = size(x, 1);
    g = (dv - rdot .* u) ./ rho;                % d(rdot)/d(position)
    H = zeros(m, 2, 4);
    H(:, 1, 1:2) = reshape(u, [m, 1, 2]);
    H(:, 2, 1:2) = reshape(g, [m, 1, 2]);
    H(:, 2, 3:4) = reshape(u, [m, 1, 2]);
  end
end

function [x, Phi] = rk4_stm(x, dt, n, mu)
  % Propagate the rows of x (m x 4) over dt by n RK4 steps, with the state transition
  % matrices Phi (m x 4 x 4).
  m = size(x, 1);
  Phi = repmat(reshape(eye(4), [1, 4, 4]), [m, 1, 1]);
  h = dt / n;
  for j = 1:n
    [k1, K1] = deriv(x, Phi, mu);
    [k2, K2] = deriv(x + h / 2 * k1, Phi + h / 2 * K1, mu);
    [k3, K3] = deriv(x + h / 2 * k2, Phi + h / 2 * K2, mu);
    [k4, K4] = deriv(x + h * k3, Phi + h * K3, mu);
    x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4);
    Phi = Phi + h / 6 * (K1 + 2 * K2 + 2 * K3 + K4);
  end
end

function [dx, dPhi] = deriv(x, Phi, mu)
  % Two-body dynamics and the variational equations dPhi = A(x) Phi, row-wise.
  rx = x(:, 1);
  ry = x(:, 2);
  r2 = rx.^2 + ry.^2;
  r = sqrt(r2);
  r3 = r2 .* r;
  r5 = r3 .* r2;
  dx = [x(:, 3), x(:, 4), -mu * rx ./ r3, -mu * ry ./ r3];
  g11 = mu * (3 * rx.^2 ./ r5 - 1 ./ r3);
  g12 = mu * 3 * rx .* ry ./ r5;
  g22 = mu * (3 * ry.^2 ./ r5 - 1 ./ r3);
  top1 = Phi(:, 1, :);
  top2 = Phi(:, 2, :);
  dPhi = cat(2, Phi(:, 3, :), Phi(:, 4, :), g11 .* top1 + g12 .* top2, g12 .* top1 + g22 .* top2);
end

function C = bmul(A, B)
  % Row-wise matrix products: C(i, :, :) = A(i, :, :) * B(i, :, :), each a plain sum in
  % a fixed order, so a row's result does not depend on the other rows.
  m = size(A, 1);
  C = reshape(sum(reshape(A, [m, size(A, 2), size(A, 3)]) .* ...
                  reshape(B, [m, 1, size(B, 2), size(B, 3)]), 3), ...
              [m, size(A, 2), size(B, 3)]);
end

function B = btrans(A)
  B = permute(A, [1, 3, 2]);
end
