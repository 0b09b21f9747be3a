-- Delete the lock KEYS[1] only if it still holds the caller's token ARGV[1] (never another holder's).
if redis.call('GET', KEYS[1]) == ARGV[1] then
  return redis.call('DEL', KEYS[1])
end
return 0
