// The participant session page: instructions per phase, the arrow keys (Phase I),
// Space or a click to intervene (Phase II), the fit, and the questionnaires.
// The drawing and the WebSocket are console.js's; this listens to its messages.
'use strict';
(function () {
  const el = (id) => document.getElementById(id);
  const send = (obj) => window.supersafeSend(obj);
  let view = { phase: 'welcome' };
  const keys = { left: false, right: false };

  const TEXT = {
    welcome: ['Welcome', 'Waiting for the session to start…'],
    phase1: ['Phase I: free driving', (v) => `Drive the robot with the left and right arrow keys for ` +
             `${v.seconds} s. It always moves forward; the arrows turn it.`],
    phase2: ['Phase II: calibration', (v) => `A robot drives straight at an obstacle. Press Space (or ` +
             `click the field) when you would stop it: the obstacle is removed. If you would let it ` +
             `pass, do nothing. Scene ${Math.min((v.done || 0) + 1, v.scenes)} of ${v.scenes}.`],
    fitting: ['Fitting', 'Learning your safe set from your interventions…'],
    fit: ['Your learned safe set', (v) => `From ${v.interventions} interventions in ${v.scenes} scenes. ` +
          'The figure shows the set learned from you (dashed) over the Standard (black) and ' +
          'Conservative (orange) sets.'],
    game: ['Phase III', (v) => `${v.game}: two robots cross the field for ${v.seconds} s. Click an ` +
           'obstacle to remove it when you believe a robot is about to hit it. Each removal costs ' +
           'half a crash.'],
    likert: ['Questions', (v) => `Compare ${v.pair[0]} and ${v.pair[1]}: 1 = much more in ${v.pair[0]}, ` +
             `4 = the same, ${v.points} = much more in ${v.pair[1]}.`],
    done: ['Thank you', 'The session is complete. You may close this page.'],
  };

  function renderLikert(v) {
    const form = el('likert');
    form.innerHTML = '';
    v.items.forEach((item) => {
      const fs = document.createElement('fieldset');
      const lg = document.createElement('legend'); lg.textContent = item.text; fs.appendChild(lg);
      for (let k = 1; k <= v.points; k++) {
        const lab = document.createElement('label');
        const r = document.createElement('input');
        r.type = 'radio'; r.name = item.key; r.value = k; r.dataset.likert = item.key;
        lab.appendChild(r); lab.appendChild(document.createTextNode(' ' + k));
        fs.appendChild(lab);
      }
      form.appendChild(fs);
    });
    const b = document.createElement('button');
    b.type = 'submit'; b.textContent = 'Submit answers'; b.dataset.action = 'answers';
    form.appendChild(b);
    form.onsubmit = (e) => {
      e.preventDefault();
      const values = {};
      v.items.forEach((item) => {
        const c = form.querySelector(`input[name="${item.key}"]:checked`);
        if (c) values[item.key] = parseInt(c.value, 10);
      });
      send({ type: 'answers', values });
    };
  }

  function show(v) {
    if (v.phase !== view.phase) el('message').textContent = '';
    view = v;
    document.body.dataset.phase = v.phase;
    document.body.dataset.waiting = v.waiting ? 'true' : 'false';
    document.body.dataset.running = v.running ? 'true' : 'false';
    const t = TEXT[v.phase] || [v.phase, ''];
    el('phase-title').textContent = t[0];
    el('phase-text').textContent = typeof t[1] === 'function' ? t[1](v) : t[1];
    const start = el('start');
    start.hidden = !v.waiting;
    start.textContent = v.phase === 'fit' ? 'Continue' : 'Start';
    const fit = v.phase === 'fit';
    el('fit-figure').hidden = !fit;
    if (fit && v.figure) el('fit-figure').src = `${v.figure}?t=${Date.now()}`;
    el('fit-lines').innerHTML = '';
    if (fit) (v.fits || []).forEach((line) => {
      const li = document.createElement('li'); li.textContent = line; el('fit-lines').appendChild(li);
    });
    const likert = el('likert');
    likert.hidden = v.phase !== 'likert';
    if (v.phase === 'likert') renderLikert(v);
  }

  el('start').addEventListener('click', () => send({ type: 'start' }));

  function interveneOnTheObstacle() {
    const o = document.querySelector('[data-obstacle-id]');
    if (o) o.dispatchEvent(new MouseEvent('click', { bubbles: true }));
  }
  el('field').addEventListener('click', (e) => {
    if (view.phase === 'phase2' && !e.target.hasAttribute('data-obstacle-id')) interveneOnTheObstacle();
  });

  function setKey(e, down) {
    if (view.phase === 'phase1' && (e.key === 'ArrowLeft' || e.key === 'ArrowRight')) {
      e.preventDefault();
      const k = e.key === 'ArrowLeft' ? 'left' : 'right';
      if (keys[k] !== down) { keys[k] = down; send({ type: 'keys', left: keys.left, right: keys.right }); }
    }
    if (down && view.phase === 'phase2' && (e.key === ' ' || e.code === 'Space')) {
      e.preventDefault();
      if (!e.repeat) interveneOnTheObstacle();
    }
  }
  document.addEventListener('keydown', (e) => setKey(e, true));
  document.addEventListener('keyup', (e) => setKey(e, false));

  document.addEventListener('supersafe-message', (e) => {
    const msg = e.detail;
    if (msg.type === 'hello' && msg.session) show(msg.session);
    else if (msg.type === 'session') show(msg);
    else if (msg.type === 'session_ack' && view.phase === 'likert') el('message').textContent = 'Thank you.';
  });
})();
